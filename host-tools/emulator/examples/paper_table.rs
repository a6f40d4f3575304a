//! Prints the paper table of the default machine (or of a plant file given as argument).
fn main() {
    let mut config = sts_emulator::MeasureConfig::default();
    if let Some(path) = std::env::args().nth(1) {
        config.plant = sts_emulator::PlantParams::from_file(std::path::Path::new(&path)).expect("plant file");
    }
    let rows = sts_emulator::paper::paper_table(&config).expect("paper table");
    print!("{}", sts_emulator::paper::format_table(&rows, false));
}

//! `import`: a lab's long recording, written by an independent tool (Python's csv module)
//! from an emulator measurement with pauses between the groups and the lab's own channel
//! names and units, comes back as the same dataset (the same group files, byte for byte, and
//! the same frequencies and strokes), and `fit` on it gives the same twin. Bad input (a
//! missing channel, a truncated file, a wrong unit, overlapping scheduled groups) gets an
//! error that names the file and the row, channel or field.

use std::path::{Path, PathBuf};
use std::process::Command;

use sts_emulator::MeasureConfig;
use sts_fit::{fit, FitConfig};

fn sts_twin(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_sts-twin")).args(args).output().expect("sts-twin runs")
}

fn path(p: &Path) -> &str {
    p.to_str().expect("a UTF-8 path")
}

fn stderr(out: &std::process::Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// The recording as a lab's logger writes it: time in ms, the command in mm, the encoder in
/// nm, the probe in volts (2.5 um per volt), the accelerometer in g; half a second at rest
/// before each group and after the last.
const WRITER: &str = r#"
import csv, json, sys
src, out = sys.argv[1], sys.argv[2]
m = json.load(open(src + "/manifest.json"))
fs = m["sample_rate_hz"]
pause = int(0.5 * fs)
k = 0
with open(out, "w", newline="") as f:
    w = csv.writer(f)
    w.writerow(["Time [ms]", "Z setpoint", "Z encoder", "Cap probe", "Acc Z"])
    def row(cmd, enc, tcp, acc):
        global k
        w.writerow([repr(k * 1000.0 / fs), repr(cmd / 1000.0), repr(enc * 1000.0), repr(tcp / 2.5), repr(acc / 9.80665)])
        k += 1
    for g in m["groups"]:
        for _ in range(pause):
            row(0.0, 0.0, 0.0, 0.0)
        with open(src + "/" + g["file"]) as gf:
            for r in csv.DictReader(gf):
                row(float(r["z_cmd_um"]), float(r["z_enc_um"]), float(r["z_tcp_um"]), float(r["acc_mps2"]))
    for _ in range(pause):
        row(0.0, 0.0, 0.0, 0.0)
"#;

/// What every writer below starts from: the original dataset's groups as one recording, half a
/// second at rest before each group and after the last: `fs`, `n` and the columns `cols` (the
/// command, encoder, probe and accelerometer in the dataset's units), numpy arrays.
const RECORDING: &str = r#"
import csv, json, sys
import numpy as np
src, out = sys.argv[1], sys.argv[2]
m = json.load(open(src + "/manifest.json"))
fs = m["sample_rate_hz"]
pause = int(0.5 * fs)
lists = [[], [], [], []]
for g in m["groups"]:
    for c in lists:
        c.extend([0.0] * pause)
    with open(src + "/" + g["file"]) as gf:
        for r in csv.DictReader(gf):
            for c, key in zip(lists, ["z_cmd_um", "z_enc_um", "z_tcp_um", "acc_mps2"]):
                c.append(float(r[key]))
for c in lists:
    c.extend([0.0] * pause)
cols = [np.array(c) for c in lists]
n = len(cols[0])
"#;

/// Runs `RECORDING` then `writer` with Python: the recording of the dataset in `src` to `out`
/// (`extra`: more arguments); `needs` names the package setup installs, for the message.
fn write_with(writer: &str, needs: &str, src: &Path, out: &Path, extra: &[&str]) {
    let script = format!("{RECORDING}{writer}");
    let py =
        Command::new("python3").args(["-c", &script, path(src), path(out)]).args(extra).output().expect("python3 runs");
    assert!(
        py.status.success(),
        "python3 with {needs} (scripts/setup-python.sh installs it): {}",
        String::from_utf8_lossy(&py.stderr)
    );
}

/// Every group file of the import equals the original's, byte for byte, with the same
/// frequency and stroke.
fn assert_same_groups(what: &str, original: &sts_dataset::Manifest, src: &Path, imported: &Path) {
    let back = sts_dataset::read(imported).unwrap_or_else(|e| panic!("{what}: the import reads: {e}"));
    assert_eq!(back.manifest.groups.len(), original.groups.len(), "{what}");
    for (a, b) in original.groups.iter().zip(&back.manifest.groups) {
        assert_eq!((a.freq_hz, a.amp_um), (b.freq_hz, b.amp_um), "{what}: {}", b.file);
        let same = std::fs::read(src.join(&a.file)).unwrap() == std::fs::read(imported.join(&b.file)).unwrap();
        assert!(same, "{what}: {} differs from the original", b.file);
    }
}

/// The recording as a pandas user writes it: `DataFrame.to_csv` with a tab, no index, no time.
const PANDAS_WRITER: &str = r#"
import pandas as pd
pd.DataFrame({
    "zref_nm": cols[0] * 1000.0,
    "zenc_um": cols[1],
    "cap_nm": cols[2] * 1000.0,
    "acc_mm_s2": cols[3] * 1000.0,
}).to_csv(out, sep="\t", index=False)
"#;

const MAP: &str = r#"
[channels]
time = { name = "Time [ms]", unit = "ms" }
command = { name = "Z setpoint", unit = "mm" }
encoder = { name = "Z encoder", unit = "nm" }
probe = { name = "Cap probe", unit = "V", scale = 2.5 }
accelerometer = { name = "Acc Z", unit = "g" }
"#;

struct Dir(PathBuf);

impl Dir {
    fn new(name: &str) -> Self {
        let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        Self(d)
    }
}

impl Drop for Dir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The original: the emulated machine, 9 groups (1, 20 and 40 Hz at 1, 6 and 11 um; the same
/// columns as the recording, no optional ones).
fn original(dir: &Path) -> sts_dataset::Dataset {
    let config = MeasureConfig {
        freqs_hz: vec![1.0, 20.0, 40.0],
        amps_um: vec![1.0, 6.0, 11.0],
        duration_s: 5.5,
        seed: 4,
        ..MeasureConfig::default()
    };
    let mut data = sts_emulator::measure::run(&config, &|_| {}).expect("measurement");
    for g in &mut data.groups {
        (g.x_mm, g.x_acc_mps2, g.spindle_deg, g.temp_c) = (None, None, None, None);
    }
    sts_dataset::write(dir, &data).unwrap();
    data
}

fn write_recording(src: &Path, out: &Path) {
    let py = Command::new("python3").args(["-c", WRITER, path(src), path(out)]).output().expect("python3 runs");
    assert!(py.status.success(), "{}", String::from_utf8_lossy(&py.stderr));
}

#[test]
fn a_labs_recording_comes_back_as_the_same_dataset_and_the_same_twin() {
    let dir = Dir::new("import-roundtrip");
    let src = dir.0.join("original");
    let data = original(&src);
    let recording = dir.0.join("logger.csv");
    write_recording(&src, &recording);
    // The accelerometer's ADC scale, as the lab knows it from its co-processor.
    let lsb = data.manifest.acc_mps2_per_lsb.expect("the emulator states its ADC scale");
    std::fs::write(dir.0.join("map.toml"), format!("acc_mps2_per_lsb = {lsb:?}\n{MAP}")).unwrap();
    let imported = dir.0.join("imported");
    let out = sts_twin(&[
        "import",
        path(&recording),
        "--out",
        path(&imported),
        "--map",
        path(&dir.0.join("map.toml")),
        "--quiet",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let table = String::from_utf8_lossy(&out.stdout);
    println!("{table}");
    assert_eq!(table.lines().count(), 1 + data.groups.len(), "a header and a line per group");

    let back = sts_dataset::read(&imported).expect("the imported dataset reads");
    assert_eq!(back.manifest.groups.len(), data.manifest.groups.len());
    assert_eq!(back.manifest.sample_rate_hz, data.manifest.sample_rate_hz);
    assert_eq!(back.manifest.acc_mps2_per_lsb, data.manifest.acc_mps2_per_lsb);
    for (i, (a, b)) in data.manifest.groups.iter().zip(&back.manifest.groups).enumerate() {
        assert_eq!((a.freq_hz, a.amp_um), (b.freq_hz, b.amp_um), "group {i}");
        // Each group follows half a second at rest.
        let expected_start_s = a.start_s + 0.5 * (i + 1) as f64;
        assert!(
            (b.start_s - expected_start_s).abs() < 1e-9,
            "group {i}: {} s, expected {expected_start_s} s",
            b.start_s
        );
        let (fa, fb) = (std::fs::read(src.join(&a.file)).unwrap(), std::fs::read(imported.join(&b.file)).unwrap());
        assert!(fa == fb, "group {i}: {} differs from the original", b.file);
    }

    // The same twin: the same formulas and held-out error from both.
    let config = FitConfig { max_epochs: 6, folds: 3, ..FitConfig::default() };
    let data = sts_dataset::read(&src).expect("the original reads");
    let m0 = fit(&data, "original", &config, &mut |_| {}).expect("fit on the original");
    let m1 = fit(&back, "imported", &config, &mut |_| {}).expect("fit on the import");
    assert_eq!(m0.amplitude.formula, m1.amplitude.formula);
    assert_eq!(m0.phase.formula, m1.phase.formula);
    assert_eq!(m0.program_postcard_hex, m1.program_postcard_hex);
    assert_eq!(m0.validation.waveform_rms_um.to_bits(), m1.validation.waveform_rms_um.to_bits());

    // A TSV written by pandas without a time channel (the mapping gives the sample rate), in
    // other units again: the command and probe in nm, the accelerometer in mm/s^2.
    let tsv = dir.0.join("logger.tsv");
    write_with(PANDAS_WRITER, "pandas", &src, &tsv, &[]);
    let pandas_map = "sample_rate_hz = 8000\n[channels]\ncommand = { name = \"zref_nm\", unit = \"nm\" }\n\
                      encoder = { name = \"zenc_um\", unit = \"um\" }\nprobe = { name = \"cap_nm\", unit = \"nm\" }\n\
                      accelerometer = { name = \"acc_mm_s2\", unit = \"mm/s^2\" }\n";
    std::fs::write(dir.0.join("no-time.toml"), pandas_map).unwrap();
    let imported_tsv = dir.0.join("imported-tsv");
    let out = sts_twin(&[
        "import",
        path(&tsv),
        "--out",
        path(&imported_tsv),
        "--map",
        path(&dir.0.join("no-time.toml")),
        "--quiet",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    for g in &data.manifest.groups {
        assert!(
            std::fs::read(src.join(&g.file)).unwrap() == std::fs::read(imported_tsv.join(&g.file)).unwrap(),
            "{}",
            g.file
        );
    }
}

/// The recording as a Simulink Real-Time log saved by SciPy's `savemat` (MAT v5, compressed):
/// the time in seconds as its own variable, the Z signals as the columns of one matrix (mm,
/// mm, volts), the accelerometer in g.
const MAT_WRITER: &str = r#"
from scipy.io import savemat
z = np.column_stack([cols[0] / 1000.0, cols[1] / 1000.0, cols[2] / 2.5])
savemat(out, {"tout": np.arange(n) / fs, "Z": z, "acc_g": cols[3] / 9.80665}, oned_as="column", do_compression=True)
"#;

#[test]
fn a_simulink_log_saved_as_a_mat_file_comes_back_as_the_same_dataset() {
    let dir = Dir::new("import-mat");
    let src = dir.0.join("original");
    let data = original(&src);
    let mat = dir.0.join("speedgoat.mat");
    write_with(MAT_WRITER, "SciPy", &src, &mat, &[]);
    let lsb = data.manifest.acc_mps2_per_lsb.expect("the emulator states its ADC scale");
    let map = format!(
        "acc_mps2_per_lsb = {lsb:?}\n[channels]\ntime = {{ name = \"tout\", unit = \"s\" }}\n\
         command = {{ name = \"Z[1]\", unit = \"mm\" }}\nencoder = {{ name = \"Z[2]\", unit = \"mm\" }}\n\
         probe = {{ name = \"Z[3]\", unit = \"V\", scale = 2.5 }}\naccelerometer = {{ name = \"acc_g\", unit = \"g\" }}\n"
    );
    std::fs::write(dir.0.join("map.toml"), &map).unwrap();
    let out_dir = dir.0.join("imported");
    let out =
        sts_twin(&["import", path(&mat), "--out", path(&out_dir), "--map", path(&dir.0.join("map.toml")), "--quiet"]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert_same_groups("the MAT-file", &data.manifest, &src, &out_dir);
    // A column the matrix does not have, and a truncated file.
    std::fs::write(dir.0.join("bad.toml"), map.replace("Z[3]", "Z[4]")).unwrap();
    let out = sts_twin(&[
        "import",
        path(&mat),
        "--out",
        path(&out_dir),
        "--map",
        path(&dir.0.join("bad.toml")),
        "--quiet",
        "--force",
    ]);
    assert!(
        !out.status.success() && stderr(&out).contains("`Z[4]`") && stderr(&out).contains("tout"),
        "{}",
        stderr(&out)
    );
    let bytes = std::fs::read(&mat).unwrap();
    let cut = dir.0.join("cut.mat");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let out = sts_twin(&[
        "import",
        path(&cut),
        "--out",
        path(&out_dir),
        "--map",
        path(&dir.0.join("map.toml")),
        "--quiet",
        "--force",
    ]);
    assert!(
        !out.status.success() && stderr(&out).contains("cut.mat") && stderr(&out).contains("truncated"),
        "{}",
        stderr(&out)
    );
}

/// The recording as an NI DAQmx task logs it, written by npTDMS: no time channel, the
/// channels by their physical names in the task's group, the positions as the controller's
/// monitor voltages (10 um per volt), the probe at 2.5 um per volt; in segments of a second,
/// as a logger streams them.
const TDMS_WRITER: &str = r#"
from nptdms import TdmsWriter, ChannelObject
scaled = [cols[0] / 10.0, cols[1] / 10.0, cols[2] / 2.5, cols[3]]
names = ["Dev1/ai0", "Dev1/ai1", "Dev1/ai2", "Dev1/ai3"]
step = int(fs)
with TdmsWriter(out) as w:
    for start in range(0, n, step):
        w.write_segment([ChannelObject("STS task", name, v[start:start + step]) for name, v in zip(names, scaled)])
"#;

#[test]
fn an_ni_daq_log_in_tdms_comes_back_as_the_same_dataset() {
    let dir = Dir::new("import-tdms");
    let src = dir.0.join("original");
    let data = original(&src);
    let tdms = dir.0.join("daq.tdms");
    write_with(TDMS_WRITER, "npTDMS", &src, &tdms, &[]);
    let lsb = data.manifest.acc_mps2_per_lsb.expect("the emulator states its ADC scale");
    let map = format!(
        "sample_rate_hz = 8000\nacc_mps2_per_lsb = {lsb:?}\n[channels]\n\
         command = {{ name = \"STS task/Dev1/ai0\", unit = \"V\", scale = 10.0 }}\n\
         encoder = {{ name = \"STS task/Dev1/ai1\", unit = \"V\", scale = 10.0 }}\n\
         probe = {{ name = \"STS task/Dev1/ai2\", unit = \"V\", scale = 2.5 }}\n\
         accelerometer = {{ name = \"STS task/Dev1/ai3\", unit = \"m/s^2\" }}\n"
    );
    std::fs::write(dir.0.join("map.toml"), &map).unwrap();
    let out_dir = dir.0.join("imported");
    let out =
        sts_twin(&["import", path(&tdms), "--out", path(&out_dir), "--map", path(&dir.0.join("map.toml")), "--quiet"]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert_same_groups("the TDMS file", &data.manifest, &src, &out_dir);
    // A channel the task did not log, and a file cut in its last segment.
    std::fs::write(dir.0.join("bad.toml"), map.replace("Dev1/ai3", "Dev1/ai7")).unwrap();
    let out = sts_twin(&[
        "import",
        path(&tdms),
        "--out",
        path(&out_dir),
        "--map",
        path(&dir.0.join("bad.toml")),
        "--quiet",
        "--force",
    ]);
    assert!(
        !out.status.success()
            && stderr(&out).contains("`STS task/Dev1/ai7`")
            && stderr(&out).contains("STS task/Dev1/ai0"),
        "{}",
        stderr(&out)
    );
    let bytes = std::fs::read(&tdms).unwrap();
    let cut = dir.0.join("cut.tdms");
    std::fs::write(&cut, &bytes[..bytes.len() - 1000]).unwrap();
    let out = sts_twin(&[
        "import",
        path(&cut),
        "--out",
        path(&out_dir),
        "--map",
        path(&dir.0.join("map.toml")),
        "--quiet",
        "--force",
    ]);
    assert!(
        !out.status.success() && stderr(&out).contains("cut.tdms") && stderr(&out).contains("truncated"),
        "{}",
        stderr(&out)
    );
}

/// The recording in HDF5, written by h5py: plain (a group `log`, the time in seconds, the Z
/// signals as a matrix with a row per sample, in mm, chunked and compressed) or as MATLAB
/// writes a MAT-file v7.3 (a 512-byte user block with MATLAB's header, each variable stored
/// transposed with its `MATLAB_class`).
const HDF5_WRITER: &str = r#"
import h5py
matlab = sys.argv[3] == "1"
t = np.arange(n) / fs
z = np.column_stack([c / 1000.0 for c in cols[:3]])
acc = cols[3]
if matlab:
    with h5py.File(out, "w", userblock_size=512) as f:
        for name, v in [("tout", t.reshape(n, 1)), ("Z", z), ("acc", acc.reshape(n, 1))]:
            d = f.create_dataset(name, data=v.T)
            d.attrs["MATLAB_class"] = np.bytes_("double")
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Fri Nov 27 12:00:00 2026 HDF5 schema 1.00 ."
    with open(out, "r+b") as f:
        f.write(header.ljust(116) + b"\0" * 8 + b"\x00\x02IM")
else:
    with h5py.File(out, "w") as f:
        g = f.create_group("log")
        g.create_dataset("time", data=t, chunks=(4096,), compression="gzip")
        g.create_dataset("z", data=z, chunks=(4096, 3), compression="gzip")
        g.create_dataset("acc", data=acc, chunks=(4096,), compression="gzip")
"#;

#[test]
fn hdf5_and_mat_v7_3_recordings_come_back_as_the_same_dataset() {
    let dir = Dir::new("import-hdf5");
    let src = dir.0.join("original");
    let data = original(&src);
    let lsb = data.manifest.acc_mps2_per_lsb.expect("the emulator states its ADC scale");
    for (file, matlab, map) in [
        (
            "log.h5",
            false,
            "[channels]\ntime = { name = \"log/time\", unit = \"s\" }\ncommand = { name = \"log/z[1]\", unit = \"mm\" }\n\
             encoder = { name = \"log/z[2]\", unit = \"mm\" }\nprobe = { name = \"log/z[3]\", unit = \"mm\" }\n\
             accelerometer = { name = \"log/acc\", unit = \"m/s^2\" }\n",
        ),
        (
            "speedgoat73.mat",
            true,
            "[channels]\ntime = { name = \"tout\", unit = \"s\" }\ncommand = { name = \"Z[1]\", unit = \"mm\" }\n\
             encoder = { name = \"Z[2]\", unit = \"mm\" }\nprobe = { name = \"Z[3]\", unit = \"mm\" }\n\
             accelerometer = { name = \"acc\", unit = \"m/s^2\" }\n",
        ),
    ] {
        let recording = dir.0.join(file);
        write_with(HDF5_WRITER, "h5py", &src, &recording, &[if matlab { "1" } else { "0" }]);
        let map = format!("acc_mps2_per_lsb = {lsb:?}\n{map}");
        std::fs::write(dir.0.join("map.toml"), &map).unwrap();
        let out_dir = dir.0.join(format!("imported-{file}"));
        let out = sts_twin(&["import", path(&recording), "--out", path(&out_dir), "--map", path(&dir.0.join("map.toml")), "--quiet"]);
        assert!(out.status.success(), "{file}: {}", stderr(&out));
        assert_same_groups(file, &data.manifest, &src, &out_dir);
        // A dataset the file lacks is named, with what it has.
        std::fs::write(dir.0.join("bad.toml"), map.replace("acc\"", "acc_x\"")).unwrap();
        let out = sts_twin(&["import", path(&recording), "--out", path(&out_dir), "--map", path(&dir.0.join("bad.toml")), "--quiet", "--force"]);
        assert!(!out.status.success() && stderr(&out).contains("acc_x`") && stderr(&out).contains(file), "{}", stderr(&out));
        // A file cut in two.
        let bytes = std::fs::read(&recording).unwrap();
        let cut = dir.0.join(format!("cut-{file}"));
        std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
        let out = sts_twin(&["import", path(&cut), "--out", path(&out_dir), "--map", path(&dir.0.join("map.toml")), "--quiet", "--force"]);
        assert!(!out.status.success() && stderr(&out).contains("cut-") && stderr(&out).contains("truncated"), "{}", stderr(&out));
        println!("{file}, cut: {}", stderr(&out).trim());
    }
}

#[test]
fn bad_recordings_and_mappings_are_refused_with_the_file_and_the_row_channel_or_field() {
    let dir = Dir::new("import-errors");
    let src = dir.0.join("original");
    original(&src);
    let recording = dir.0.join("logger.csv");
    write_recording(&src, &recording);
    let import = |rec: &Path, map_text: &str| {
        let map = dir.0.join("map.toml");
        std::fs::write(&map, map_text).unwrap();
        let out = sts_twin(&["import", path(rec), "--out", path(&dir.0.join("out")), "--map", path(&map), "--quiet"]);
        assert!(!out.status.success(), "accepted");
        assert!(!stderr(&out).contains("panicked"), "{}", stderr(&out));
        stderr(&out)
    };
    // A channel the recording lacks: named, with the channels it has.
    let err = import(&recording, &MAP.replace("\"Acc Z\"", "\"Acc X\""));
    assert!(
        err.contains("logger.csv")
            && err.contains("`Acc X`")
            && err.contains("accelerometer")
            && err.contains("Cap probe"),
        "{err}"
    );
    // A truncated file: the last row cut in its middle.
    let text = std::fs::read_to_string(&recording).unwrap();
    let cut = text.trim_end().rfind(',').unwrap();
    let truncated = dir.0.join("truncated.csv");
    std::fs::write(&truncated, &text[..cut]).unwrap();
    let rows = text.trim_end().lines().count();
    let err = import(&truncated, MAP);
    assert!(
        err.contains(&format!("truncated.csv:{rows}:")) && err.contains("Acc Z") && err.contains("truncated"),
        "{err}"
    );
    // A unit that is not the channel's.
    let err = import(&recording, &MAP.replace("unit = \"nm\"", "unit = \"g\""));
    assert!(err.contains("map.toml") && err.contains("channels.encoder.unit") && err.contains("`g`"), "{err}");
    // A value that is not a number.
    let bad = dir.0.join("bad-value.csv");
    std::fs::write(&bad, text.replacen("\n0.125,0.0,", "\n0.125,n/a,", 1)).unwrap();
    let err = import(&bad, MAP);
    assert!(err.contains("bad-value.csv:3:") && err.contains("Z setpoint") && err.contains("`n/a`"), "{err}");
    // A row missing in the middle: the time jumps two steps.
    let skipped = dir.0.join("skipped.csv");
    let lines: Vec<&str> = text.lines().collect();
    std::fs::write(&skipped, [&lines[..99], &lines[100..]].concat().join("\n")).unwrap();
    let err = import(&skipped, MAP);
    assert!(
        err.contains("skipped.csv:100:") && err.contains("Time [ms]") && err.contains("advances by 2.500000e-4 s"),
        "{err}"
    );
    // Scheduled groups that overlap.
    let err = import(
        &recording,
        &format!("{MAP}\n[[schedule]]\nstart_s = 0.5\nduration_s = 6\n\n[[schedule]]\nstart_s = 6.0\nduration_s = 6\n"),
    );
    assert!(err.contains("schedule[0] and schedule[1]") && err.contains("overlap"), "{err}");
    // A format this importer does not read yet.
    let parquet = dir.0.join("log.parquet");
    std::fs::write(&parquet, b"PAR1").unwrap();
    let err = import(&parquet, MAP);
    assert!(err.contains("log.parquet") && err.contains(".parquet") && err.contains(".tdms"), "{err}");
}

#[test]
fn a_schedule_cuts_the_groups_at_its_times() {
    let dir = Dir::new("import-schedule");
    let src = dir.0.join("original");
    let data = original(&src);
    let recording = dir.0.join("logger.csv");
    write_recording(&src, &recording);
    // The first two groups by their times in the recording (each after 0.5 s at rest).
    let d = 5.5;
    let map = format!(
        "{MAP}\n[[schedule]]\nstart_s = 0.5\nduration_s = {d}\n\n[[schedule]]\nstart_s = {}\nduration_s = {d}\n",
        0.5 + d + 0.5
    );
    std::fs::write(dir.0.join("map.toml"), map).unwrap();
    let out_dir = dir.0.join("out");
    let out = sts_twin(&[
        "import",
        path(&recording),
        "--out",
        path(&out_dir),
        "--map",
        path(&dir.0.join("map.toml")),
        "--quiet",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let back = sts_dataset::read(&out_dir).unwrap();
    assert_eq!(back.groups.len(), 2);
    for (a, b) in data.manifest.groups.iter().zip(&back.manifest.groups) {
        assert_eq!((a.freq_hz, a.amp_um), (b.freq_hz, b.amp_um));
        assert!(std::fs::read(src.join(&a.file)).unwrap() == std::fs::read(out_dir.join(&b.file)).unwrap());
    }
}

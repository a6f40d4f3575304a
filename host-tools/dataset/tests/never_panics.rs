//! Arbitrary bytes as a group file or a manifest: an error or a dataset, never a panic.

use proptest::prelude::*;
use std::path::Path;

const HEADER: &str = "t_s,z_cmd_um,z_enc_um,z_tcp_um,acc_mps2\n";

proptest! {
    #[test]
    fn group_csv_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let _ = sts_dataset::parse_group_csv(Path::new("g.csv"), &bytes, 8000.0);
        let mut with_header = HEADER.as_bytes().to_vec();
        with_header.extend_from_slice(&bytes);
        let _ = sts_dataset::parse_group_csv(Path::new("g.csv"), &with_header, 8000.0);
    }

    #[test]
    fn csv_like_text_never_panics(text in "[0-9.,eE+\\-\\r\\n a-z_]{0,300}") {
        let mut with_header = HEADER.to_string();
        with_header.push_str(&text);
        let _ = sts_dataset::parse_group_csv(Path::new("g.csv"), with_header.as_bytes(), 8000.0);
    }

    #[test]
    fn manifest_never_panics(text in "\\PC{0,300}") {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("manifest.json"), &text).unwrap();
        let _ = sts_dataset::read(dir.path());
    }
}

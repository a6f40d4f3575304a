//! What the manifest's rows and checksums catch, the physical bounds, and the output module:
//! a dataset replaced as a unit, outputs refused where they would overwrite data or an input.

use std::path::Path;
use sts_dataset::output::{check_dataset_dir, check_file, check_files, StagedDir};
use sts_dataset::{read, write, Dataset, DatasetError, GroupData, GroupInfo, Manifest};

fn dataset(groups: usize, offset_um: f64) -> Dataset {
    let mut data = Vec::new();
    let mut infos = Vec::new();
    for g in 0..groups {
        let mut group = GroupData::with_len(50);
        for i in 0..50 {
            group.t_s[i] = i as f64 / 8000.0;
            group.z_tcp_um[i] = offset_um + i as f64 * 1e-3;
        }
        data.push(group);
        infos.push(GroupInfo::new(&format!("g{g:03}.csv"), 5.0, 1.0, g as f64));
    }
    Dataset { manifest: Manifest::new(8000.0, "checks", infos), groups: data }
}

#[test]
fn the_manifest_records_each_file_and_a_file_of_another_run_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    write(&a, &dataset(2, 0.0)).unwrap();
    write(&b, &dataset(2, 1.0)).unwrap();
    let manifest = sts_dataset::read_manifest(&a).unwrap();
    assert_eq!(manifest.groups[1].rows, Some(50));
    let bytes = std::fs::read(a.join("g001.csv")).unwrap();
    assert_eq!(manifest.groups[1].crc32, Some(sts_dataset::group_checksum(&bytes)));
    // Same shape, other values: only the checksum tells.
    std::fs::copy(b.join("g001.csv"), a.join("g001.csv")).unwrap();
    let err = read(&a).unwrap_err();
    assert!(matches!(err, DatasetError::Mismatch { group: 1, .. }), "{err}");
    assert!(err.to_string().contains("g001.csv: not the file the manifest describes"), "{err}");
    // Cut short.
    std::fs::write(a.join("g001.csv"), &bytes[..bytes.len() / 2]).unwrap();
    let err = read(&a).unwrap_err().to_string();
    assert!(err.contains("data rows where the manifest says 50"), "{err}");
}

#[test]
fn a_manifest_without_checksums_still_reads() {
    let dir = tempfile::tempdir().unwrap();
    let data = dataset(2, 0.0);
    write(dir.path(), &data).unwrap();
    sts_dataset::write_manifest(dir.path(), &data.manifest).unwrap();
    let text = std::fs::read_to_string(dir.path().join("manifest.json")).unwrap();
    assert!(!text.contains("crc32") && !text.contains("rows"), "{text}");
    assert_eq!(read(dir.path()).unwrap().groups.len(), 2);
    let bad = text.replacen("\"start_s\": 0.0", "\"start_s\": 0.0, \"crc32\": \"XYZ\"", 1);
    std::fs::write(dir.path().join("manifest.json"), bad).unwrap();
    let err = read(dir.path()).unwrap_err().to_string();
    assert!(err.contains("manifest.json:") && err.contains("8 lower-case hex digits"), "{err}");
}

#[test]
fn values_beyond_a_channels_bounds_are_refused_read_and_written() {
    let header = "t_s,z_cmd_um,z_enc_um,z_tcp_um,acc_mps2\n";
    for (row, column, expect) in [
        ("0.000125,0,0,1e308,0", 4, "`z_tcp_um`: 1e308 is beyond"),
        ("0.000125,0,0,0,-2e5", 5, "`acc_mps2`: -2e5 is beyond"),
        ("0.000125,1.5e6,0,0,0", 2, "`z_cmd_um`: 1.5e6 is beyond"),
    ] {
        let text = format!("{header}0,0,0,0,0\n{row}\n0.00025,0,0,0,0\n");
        let err = sts_dataset::parse_group_csv(Path::new("g.csv"), text.as_bytes(), 8000.0).unwrap_err();
        let col = row.split(',').take(column - 1).map(|f| f.len() + 1).sum::<usize>() + 1;
        let at = format!("g.csv:3:{col}:");
        assert!(matches!(err, DatasetError::OutOfRange { line: 3, .. }), "{err}");
        assert!(err.to_string().contains(&at) && err.to_string().contains(expect), "{err}");
    }
    let mut data = dataset(1, 0.0);
    data.groups[0].z_tcp_um[7] = 2e6;
    let dir = tempfile::tempdir().unwrap();
    let err = write(&dir.path().join("d"), &data).unwrap_err().to_string();
    assert!(err.contains("`z_tcp_um` sample 7: 2e6 is beyond"), "{err}");
    assert!(!dir.path().join("d").exists());
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "a refused write left files");
}

#[test]
fn a_dataset_is_replaced_as_a_unit_and_only_with_force() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().join("d");
    check_dataset_dir(&d, false, &[]).unwrap();
    write(&d, &dataset(3, 0.0)).unwrap();
    let err = check_dataset_dir(&d, false, &[]).unwrap_err().to_string();
    assert!(err.contains("holds a dataset (--force"), "{err}");
    check_dataset_dir(&d, true, &[]).unwrap();
    // A staged directory dropped unfinished leaves the old one and nothing else.
    {
        let staged = StagedDir::new(&d).unwrap();
        write(staged.path(), &dataset(1, 5.0)).unwrap();
    }
    assert_eq!(read(&d).unwrap().groups.len(), 3);
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    // Replaced whole: no file of the old one is left.
    write(&d, &dataset(1, 5.0)).unwrap();
    assert_eq!(read(&d).unwrap().groups.len(), 1);
    assert!(!d.join("g002.csv").exists());
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    // Other files, a file, an input: never.
    let other = dir.path().join("other");
    std::fs::create_dir(&other).unwrap();
    std::fs::write(other.join("notes.txt"), "x").unwrap();
    assert!(check_dataset_dir(&other, true, &[]).unwrap_err().to_string().contains("no dataset"));
    assert!(check_dataset_dir(&other.join("notes.txt"), true, &[]).is_err());
    let plant = d.join("plant.toml");
    assert!(check_dataset_dir(&d, true, &[&plant]).unwrap_err().to_string().contains("an input"));
}

#[test]
fn files_are_refused_onto_inputs_into_datasets_and_twice() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().join("d");
    write(&d, &dataset(1, 0.0)).unwrap();
    let model = dir.path().join("m.json");
    std::fs::write(&model, "{}").unwrap();
    for (path, force, inputs, expect) in [
        (d.join("manifest.json"), true, vec![], "written only as a whole"),
        (d.join("new.csv"), true, vec![], "written only as a whole"),
        (model.clone(), true, vec![model.as_path()], "an input"),
        (model.clone(), false, vec![], "already exists (--force"),
        (d.clone(), true, vec![], "is a directory"),
    ] {
        let err = check_file(&path, force, &inputs).unwrap_err().to_string();
        assert!(err.contains(expect), "{}: {err}", path.display());
    }
    check_file(&model, true, &[]).unwrap();
    let out = dir.path().join("out.json");
    let same = dir.path().join(".").join("out.json");
    assert!(check_files(&[&out, &same], true, &[]).unwrap_err().to_string().contains("two outputs"));
}

//! Every broken scene in `scenes/bad/` is run through the real binary; each file's header
//! says the exit code (`// expect-exit: N`) and a fragment of the message
//! (`// expect-stderr: ...`) it must produce. Nothing may panic.

use std::path::Path;
use std::process::Command;

#[test]
fn every_bad_scene_fails_with_its_message() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    let bad = root.join("scenes/bad");
    let out = std::env::temp_dir().join(format!("sinew-bad-scenes-{}", std::process::id()));
    let mut files: Vec<_> = std::fs::read_dir(&bad)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "ron"))
        .collect();
    files.sort();
    assert!(
        files.len() >= 7,
        "expected the broken scenes, found {files:?}"
    );
    for file in files {
        let text = std::fs::read_to_string(&file).unwrap();
        let header = |key: &str| {
            text.lines()
                .find_map(|l| l.strip_prefix(key))
                .map(str::trim)
                .unwrap_or_else(|| panic!("{}: no `{key}` header", file.display()))
                .to_string()
        };
        let exit: i32 = header("// expect-exit:").parse().unwrap();
        let fragment = header("// expect-stderr:");
        let output = Command::new(env!("CARGO_BIN_EXE_xtask"))
            .args(["run-scene", "--quiet", "--out"])
            .arg(&out)
            .arg(&file)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(
            output.status.code(),
            Some(exit),
            "{}: {stderr}",
            file.display()
        );
        assert!(
            stderr.contains(&fragment),
            "{}: expected {fragment:?} in {stderr:?}",
            file.display()
        );
        assert!(!stderr.contains("panicked"), "{}: {stderr}", file.display());
    }
    let _ = std::fs::remove_dir_all(&out);
}

/// A file that is not UTF-8 (it cannot live in `scenes/bad/`, whose files the tidy test
/// reads as text) fails like a syntax error: exit code 2 and the line and column of its
/// first bad byte.
#[test]
fn a_file_that_is_not_utf8_fails_at_its_first_bad_byte() {
    let dir = std::env::temp_dir().join(format!("sinew-not-utf8-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("not-utf8.ron");
    std::fs::write(
        &file,
        b"Scene(\n    description: \"bad \xff byte\",\n    tasks: [],\n)\n",
    )
    .unwrap();
    let output = Command::new(env!("CARGO_BIN_EXE_xtask"))
        .args(["run-scene", "--quiet", "--no-render", "--out"])
        .arg(dir.join("out"))
        .arg(&file)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("not-utf8.ron:2:23: the file is not UTF-8 text"),
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}

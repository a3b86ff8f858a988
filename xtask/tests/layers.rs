//! `cargo xtask layers` on a small workspace of its own: the circle is
//! reported and fails the command, and `lint`, which checks it first, stops
//! there without running cargo.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn workspace(name: &str, files: &[(&str, &str)]) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("xtask-layers-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    for (path, text) in files {
        let path = dir.join(path);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, text).unwrap();
    }
    dir
}

fn xtask(dir: &Path, command: &str) -> Output {
    Command::new(env!("CARGO_BIN_EXE_xtask"))
        .arg(command)
        .current_dir(dir)
        // `lint` must stop at the circle: a cargo that cannot run shows if it did not.
        .env("CARGO", dir.join("no-such-cargo"))
        .env("CVD_XTASK_NO_SETUP", "1")
        .output()
        .unwrap()
}

const ROOT: &[(&str, &str)] = &[
    ("rust-toolchain.toml", "[toolchain]\nchannel = \"stable\"\n"),
    ("xtask/install-deps", "#!/bin/sh\n"),
    ("Cargo.toml", "[workspace]\nmembers = [\n  \"one\",\n  \"two\", # the second\n]\n"),
    ("one/Cargo.toml", "[package]\nname = \"one\"\n"),
    ("two/Cargo.toml", "[package]\nname = \"two\"\n"),
    ("two/src/main.rs", "mod low;\nmod high;\nfn main() {}\n"),
    ("two/src/low.rs", "pub fn f() {}\n"),
    ("two/src/high.rs", "use crate::low::f;\n"),
];

#[test]
fn a_circle_fails_layers_and_lint() {
    let mut files = ROOT.to_vec();
    files.extend([
        ("one/src/lib.rs", "pub mod a;\npub mod b;\n"),
        ("one/src/a.rs", "use crate::b::B;\npub struct A;\n"),
        ("one/src/b/mod.rs", "pub struct B;\nmod inner;\n"),
        ("one/src/b/inner.rs", "// crate::a in a comment\nfn f() -> super::super::a::A { super::super::a::A }\n"),
    ]);
    let dir = workspace("circle", &files);
    let out = xtask(&dir, "layers");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stdout}{stderr}");
    assert!(stdout.contains("layers: one: 2 modules, 1 circle:"), "{stdout}");
    assert!(stdout.contains("a -> b  one/src/a.rs:1\n"), "{stdout}");
    assert!(stdout.contains("b -> a  one/src/b/inner.rs:2 (and 1 more)\n"), "{stdout}");
    assert!(stdout.contains("layers: two (bin): 2 modules, no circles; bottom-up: low < high\n"), "{stdout}");
    assert!(stderr.contains("import each other in circles"), "{stderr}");

    let out = xtask(&dir, "lint");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("import each other in circles") && !stderr.contains("no-such-cargo"), "{stderr}");
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn no_circle_passes() {
    let mut files = ROOT.to_vec();
    files.extend([
        ("one/src/lib.rs", "pub mod a;\npub mod b;\n"),
        ("one/src/a.rs", "use crate::b::B;\n"),
        ("one/src/b.rs", "pub struct B;\n#[cfg(test)]\nmod tests {\n    use crate::a;\n}\n"),
    ]);
    let dir = workspace("ok", &files);
    let out = xtask(&dir, "layers");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0), "{stdout}{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(
        stdout,
        "layers: one: 2 modules, no circles; bottom-up: b < a\n\
         layers: two (bin): 2 modules, no circles; bottom-up: low < high\n"
    );
    let _ = std::fs::remove_dir_all(dir);
}

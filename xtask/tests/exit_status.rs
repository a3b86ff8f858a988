//! `cargo xtask` passes the exit status of the command it runs through
//! unchanged: cargo is replaced here (through `$CARGO`, which the xtask
//! runs) by a script that ends as told.

use std::path::PathBuf;
use std::process::Command;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::OnceLock;

/// A stand-in for cargo that exits with `$FAKE_EXIT`, or is killed by
/// `$FAKE_SIGNAL`, and logs its arguments to `$FAKE_LOG`; written once (a
/// script being rewritten while another test runs it is busy).
fn fake_cargo() -> PathBuf {
    static CARGO: OnceLock<PathBuf> = OnceLock::new();
    CARGO.get_or_init(write_fake_cargo).clone()
}

fn write_fake_cargo() -> PathBuf {
    let dir = std::env::temp_dir().join(format!("xtask-exit-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("cargo");
    std::fs::write(
        &path,
        "#!/bin/sh\necho \"$@\" >> \"$FAKE_LOG\"\n\
         if [ -n \"$FAKE_SIGNAL\" ]; then kill -s \"$FAKE_SIGNAL\" $$; fi\nexit \"$FAKE_EXIT\"\n",
    )
    .unwrap();
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    path
}

fn xtask(args: &[&str], exit: i32, signal: Option<&str>) -> (Option<i32>, String) {
    let cargo = fake_cargo();
    // Tests run in parallel: each call logs to a file of its own.
    static CALLS: AtomicUsize = AtomicUsize::new(0);
    let log = cargo.with_extension(format!("{}.log", CALLS.fetch_add(1, Ordering::SeqCst)));
    let _ = std::fs::remove_file(&log);
    let status = Command::new(env!("CARGO_BIN_EXE_xtask"))
        .args(args)
        .env("CARGO", &cargo)
        .env("CVD_XTASK_NO_SETUP", "1")
        .env("FAKE_EXIT", exit.to_string())
        .env("FAKE_SIGNAL", signal.unwrap_or(""))
        .env("FAKE_LOG", &log)
        .status()
        .unwrap();
    (status.code(), std::fs::read_to_string(&log).unwrap_or_default())
}

#[test]
fn the_exit_status_passes_through() {
    for code in [0, 1, 2, 3, 101] {
        let (got, log) = xtask(&["run", "--backend", "cpu", "--model", "no-such-model"], code, None);
        assert_eq!(got, Some(code), "run: {log}");
        assert!(log.contains("--no-default-features -- run --backend cpu --model no-such-model"), "{log}");
        let (got, log) = xtask(&["test", "--no-run"], code, None);
        assert_eq!(got, Some(code), "test: {log}");
    }
    // Killed by a signal: 128 + its number, as a shell says it.
    let (got, _) = xtask(&["run", "--backend", "cpu"], 0, Some("TERM"));
    assert_eq!(got, Some(128 + 15));
}

#[test]
fn auto_lists_the_devices_first_and_stops_if_that_fails() {
    // With the default backend, the devices are listed by a build without
    // the kernels; its failure is passed on before anything else runs.
    let (got, log) = xtask(&["run", "--model", "cube"], 2, None);
    assert_eq!(got, Some(2));
    assert_eq!(log.lines().count(), 1, "{log}");
    assert!(log.contains("--no-default-features -- devices --json"), "{log}");
    // --backend vulkan builds the kernels (the default features) at once.
    let (got, log) = xtask(&["run", "--backend=vulkan"], 0, None);
    assert_eq!(got, Some(0));
    assert!(!log.contains("--no-default-features") && log.contains("-- run --backend=vulkan"), "{log}");
}

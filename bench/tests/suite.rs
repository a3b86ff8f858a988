//! `cargo xtask bench paper` end to end at its reduced size: every section
//! runs on every backend at hand and writes well-formed tables, JSON and
//! charts. Timings are printed, never asserted.

use cvd_bench::{Config, Section};
use std::path::Path;

fn png_size(path: &Path) -> (u32, u32) {
    let file = std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let info = png::Decoder::new(std::io::BufReader::new(file)).read_info().unwrap();
    (info.info().width, info.info().height)
}

#[test]
fn quick_suite_writes_every_section() {
    let out = std::env::temp_dir().join(format!("cvd-bench-paper-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let mut config = Config::quick(out.clone());
    config.threads = Some(2);
    config.vulkan = cvd_tests::vulkan().is_some();
    let report = cvd_bench::run(&config).expect("the suite runs");

    let backends: Vec<&str> = if config.vulkan { vec!["cpu", "vulkan"] } else { vec!["cpu"] };
    for section in Section::ALL {
        for backend in &backends {
            let rows: Vec<_> =
                report.rows.iter().filter(|r| r.section == section.name() && r.backend == *backend).collect();
            assert!(!rows.is_empty(), "no {backend} rows in {}", section.name());
            for r in rows {
                assert!(r.total_ms > 0.0 && r.total_ms.is_finite(), "{r:?}");
                assert!(r.e_vol <= 1e-5, "volume lost: {r:?}");
                assert_eq!(r.counters.unresolved, 0, "{r:?}");
            }
        }
    }
    // Table 1: three built-in models, three methods, per backend, and whole
    // cells on the CPU backend.
    assert_eq!(report.rows.iter().filter(|r| r.section == "table1").count(), 9 * backends.len() + 3);
    // Fig. 13 follows Lloyd: the energy of each method's run never rises.
    let fig13: Vec<_> = report.rows.iter().filter(|r| r.section == "fig13").collect();
    for w in fig13.windows(2) {
        if w[0].backend == w[1].backend && w[0].method() == w[1].method() && w[1].iteration > w[0].iteration {
            assert!(w[1].energy <= w[0].energy * (1.0 + 1e-6), "{:?} then {:?}", w[0], w[1]);
        }
    }
    // The Vulkan rows report their device memory.
    assert!(report.rows.iter().filter(|r| r.backend == "vulkan").all(|r| r.peak_device_mib.is_some_and(|m| m > 0.0)));

    let md = std::fs::read_to_string(out.join("paper.md")).unwrap();
    for heading in ["## Table 1", "## Fig. 7", "## Fig. 8", "## Fig. 12", "## Fig. 13", "## Scale"] {
        assert!(md.contains(heading), "paper.md lacks {heading}");
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("paper.json")).unwrap()).unwrap();
    assert_eq!(json["rows"].as_array().map(Vec::len), Some(report.rows.len()));
    let charts: Vec<_> = report.files.iter().filter(|f| f.extension().is_some_and(|e| e == "png")).collect();
    for prefix in ["fig7_", "fig8_", "fig12_", "fig13_", "scale_"] {
        assert!(
            charts.iter().any(|f| f.file_name().unwrap().to_str().unwrap().starts_with(prefix)),
            "no {prefix} chart"
        );
    }
    for chart in charts {
        assert_eq!(png_size(chart), (800, 500));
        assert!(md.contains(chart.file_name().unwrap().to_str().unwrap()), "paper.md does not show {chart:?}");
    }
    let _ = std::fs::remove_dir_all(&out);
}

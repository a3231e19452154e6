//! `deltaloop paper`: the folder is complete (every table and figure, non-trivial) and the numbers
//! in report.md are the ones in summary.json.

mod common;

use common::{deltaloop, summary};
use serde_json::Value;

#[test]
fn paper_folder_is_complete_and_report_matches_summary() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("paper");
    let o = deltaloop(&["paper", "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        stdout.contains("STA beats IS?") && stdout.lines().count() < 40,
        "one screen: {stdout}"
    );

    let s = summary(&out);
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    let cases = s["cases"].as_array().unwrap();
    assert_eq!(cases.len(), 6, "3 scenarios × 2 presets");
    let fmt = |v: &Value| format!("{:.3e}", v.as_f64().unwrap());
    for c in cases {
        let preset = c["preset"].as_str().unwrap();
        // Every law's RMS row in report.md carries exactly summary.json's numbers.
        for law in ["tde-is", "tdc-is-sta", "tdc", "pid"] {
            let rms = &c["laws"][law]["rms_rad"];
            let row = format!("| ours, `{preset}` |");
            let want = format!(
                "(`{law}`) | {} | {} | {} |",
                fmt(&rms[0]),
                fmt(&rms[1]),
                fmt(&rms[2])
            );
            assert!(
                report
                    .lines()
                    .any(|l| l.starts_with(&row) && l.ends_with(&want)),
                "{preset} {law}: no row ending {want}"
            );
        }
        // The explicit-vs-implicit table: one row per law, its numbers those of summary.json.
        let scn = c["scenario"].as_str().unwrap();
        for law in ["tde-is", "tdc-is-sta", "tdc-is-ista"] {
            let m = &c["laws"][law];
            let mx = |k: &str| {
                m[k].as_array()
                    .unwrap()
                    .iter()
                    .map(|v| v.as_f64().unwrap())
                    .fold(0.0, f64::max)
            };
            let row = format!(
                "| {} | `{preset}` | `{law}` | {:.3e} | {:.3e} | {:.4} | {:.1} | {} |",
                scn.to_uppercase(),
                mx("rms_rad"),
                mx("max_abs_err_rad"),
                mx("hf_torque_share"),
                mx("torque_tv_nm"),
                m["clamp_count"].as_u64().unwrap()
            );
            let section = report
                .split("## Explicit vs implicit super-twisting")
                .nth(1)
                .expect("no explicit-vs-implicit section");
            assert!(
                section.lines().any(|l| l == row),
                "{preset} {law}: no row {row}"
            );
        }
        // Figures: errors, torques, chatter zoom, 3-D path, explicit-vs-implicit torque; PNG and
        // SVG, real content.
        let figs = c["figures"].as_array().unwrap();
        assert_eq!(figs.len(), 5);
        assert_eq!(figs[4], format!("fig-{scn}-{preset}-sta-torque"));
        for f in figs {
            let f = f.as_str().unwrap();
            assert!(
                report.contains(&format!("({f}.png)")),
                "report does not embed {f}"
            );
            let png = std::fs::read(out.join(format!("{f}.png"))).unwrap();
            assert!(png.starts_with(b"\x89PNG"));
            let (w, h) = (
                u32::from_be_bytes(png[16..20].try_into().unwrap()),
                u32::from_be_bytes(png[20..24].try_into().unwrap()),
            );
            assert!(
                w >= 800 && h >= 400 && png.len() > 20_000,
                "{f}.png {w}x{h}, {} bytes",
                png.len()
            );
            let svg = std::fs::read_to_string(out.join(format!("{f}.svg"))).unwrap();
            // Each series is a polyline with many points (not an empty chart).
            let longest = svg
                .split("<polyline")
                .skip(1)
                .map(|p| {
                    p.split("points=\"")
                        .nth(1)
                        .map_or(0, |q| q.split('"').next().unwrap_or("").split(' ').count())
                })
                .max()
                .unwrap_or(0);
            assert!(longest > 40, "{f}.svg: longest series has {longest} points");
        }
        // The normal run folder of this case is there too.
        let rf = out.join(c["run_folder"].as_str().unwrap());
        for file in ["trace.csv", "summary.json", "report.md", "config.toml"] {
            assert!(rf.join(file).exists(), "{} lacks {file}", rf.display());
        }
    }
    // The published values, the verdicts and the limit-cycle explanation with this run's numbers.
    for v in ["3.463e-4", "4.400e-3", "5.592e-4"] {
        assert!(report.contains(v), "published value {v} missing");
    }
    assert_eq!(
        report.matches("Does the proposal beat TDC+IS here").count(),
        3
    );
    let s1_paper = cases
        .iter()
        .find(|c| c["preset"] == "paper" && c["scenario"] == "s1")
        .unwrap();
    let clamps = s1_paper["laws"]["tdc-is-sta"]["clamp_count"]
        .as_u64()
        .unwrap();
    assert!(
        clamps > 0 && report.contains(&format!("clamp in {clamps} of")),
        "limit cycle not explained with its numbers"
    );
    // The comparison's sentences quote the numbers of this run.
    let ista_clamps = s1_paper["laws"]["tdc-is-ista"]["clamp_count"]
        .as_u64()
        .unwrap();
    assert!(report.contains("With M̄ matched to this robot (preset `matched`), the implicit law's"));
    assert!(
        report.contains(&format!("clamp in S1 {ista_clamps},")),
        "the paper-preset sentence does not quote tdc-is-ista's clamped intervals"
    );
}

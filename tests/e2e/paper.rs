//! `deltaloop paper`: the folder is complete (every table and figure, non-trivial) and the numbers
//! in report.md are the ones in summary.json.

use crate::common;
use deltaloop_study::record::sensitivity;

use common::{deltaloop, summary};
use serde_json::Value;

#[test]
fn paper_folder_is_complete_and_report_matches_summary() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("paper");
    let o = deltaloop(&[
        "paper",
        "--seeds",
        "4",
        "--realtime-runs",
        "1",
        "--out",
        out.to_str().unwrap(),
    ]);
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
        // Every law's RMS row in report.md carries summary.json's numbers, to the digits its
        // round-off twin leaves: all four when the twin moved it by < 5e-5, fewer when it moved
        // it by more than 1e-3, and the printed value within its last digit.
        for law in ["tde-is", "tdc-is-sta", "tdc", "pid"] {
            let rms = &c["laws"][law]["rms_rad"];
            let rel = c["laws"][law]["sensitivity"]["rms_rel"].as_f64().unwrap();
            let head = format!("| ours, `{preset}` |");
            let scn = c["scenario"].as_str().unwrap().to_uppercase();
            let section = report
                .split(&format!("## {scn} — Table"))
                .nth(1)
                .and_then(|t| t.split("\n## ").next())
                .unwrap_or_else(|| panic!("no {scn} section"));
            let line = section
                .lines()
                .find(|l| l.starts_with(&head) && l.contains(&format!("(`{law}`)")))
                .unwrap_or_else(|| panic!("{preset} {law}: no row"));
            let cells: Vec<&str> = line.split('|').map(str::trim).collect();
            for j in 0..3 {
                let shown = cells[3 + j];
                let mantissa = shown.split('e').next().unwrap();
                let digits = mantissa.chars().filter(char::is_ascii_digit).count();
                let exact = rms[j].as_f64().unwrap();
                if rel < 5e-5 {
                    assert_eq!(shown, fmt(&rms[j]), "{preset} {law}: {line}");
                } else {
                    assert!(rel < 1e-3 || digits < 4, "{preset} {law} rel {rel}: {line}");
                    let v: f64 = shown.parse().unwrap();
                    let exp = exact.abs().log10().floor() as i32;
                    let unit = 10f64.powi(exp - digits as i32 + 1);
                    assert!(
                        (v - exact).abs() <= unit / 2.0 * 1.000001,
                        "{shown} vs {exact}"
                    );
                }
            }
            assert_ne!(cells[6], "–", "{preset} {law}: no round-off cell: {line}");
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
            // Each figure with the digits the law's round-off spreads leave (the RMS and max error
            // their own, the HF share and torque variation the largest).
            let se = &m["sensitivity"];
            let rel = |k: &str| se[k].as_f64().unwrap_or(0.0);
            let worst = ["rms_rel", "max_err_rel", "task_rms_rel", "tde_rel"]
                .iter()
                .map(|k| rel(k))
                .fold(0.0, f64::max);
            let row = format!(
                "| {} | `{preset}` | `{law}` | {} | {} | {} | {} | {} |",
                scn.to_uppercase(),
                sensitivity::sci(mx("rms_rad"), rel("rms_rel")),
                sensitivity::sci(mx("max_abs_err_rad"), rel("max_err_rel")),
                sensitivity::fixed(mx("hf_torque_share"), 4, worst),
                sensitivity::fixed(mx("torque_tv_nm"), 1, worst),
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
    robustness_table_is_the_seeds_runs(&out, &s, &report);
}

/// The robustness table: 6 in-process rows over the 4 seeds asked for, 3 realtime rows of the one
/// run asked for (with its round trip), and its S2 `matched` ratio is the geometric mean of the
/// per-seed ratios of `deltaloop run` with the documented sensor.
fn robustness_table_is_the_seeds_runs(out: &std::path::Path, s: &Value, report: &str) {
    let r = &s["robustness"];
    let rows = r["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 9, "{r}");
    let (inproc, rt): (Vec<&Value>, Vec<&Value>) = rows.iter().partition(|x| x["mode"] == "inproc");
    assert!(inproc.iter().all(|x| x["runs"] == 4), "{r}");
    assert_eq!(rt.len(), 3);
    for x in &rt {
        assert_eq!(x["preset"], "matched");
        let n = x["runs"].as_u64().unwrap() + x["left_out"].as_u64().unwrap();
        assert_eq!(n, 1, "{x}");
        if x["runs"] == 1 {
            assert!(x["round_trip_p50_us"].as_f64().unwrap() > 0.0, "{x}");
        }
    }
    let rows = inproc;
    assert!(report.contains("## Robustness: does the ranking hold"));
    let sensor = &r["sensor"];
    let row = rows
        .iter()
        .find(|x| x["scenario"] == "s2" && x["preset"] == "matched")
        .unwrap();
    let geo = row["sta_over_is"]["geo_mean"].as_f64().unwrap();
    let cfg = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/s2-fast.toml"),
    )
    .unwrap();
    let cfg = format!(
        "{cfg}\n[sensor]\nencoder_counts_per_rev = {}\nq_noise_std_rad = {}\nqd_noise_std_rad_s = {}\n",
        sensor["encoder_counts_per_rev"], sensor["q_noise_std_rad"], sensor["qd_noise_std_rad_s"]
    );
    let path = out.join("s2-noisy.toml");
    std::fs::write(&path, cfg).unwrap();
    let mut logs = Vec::new();
    for seed in 1..=4 {
        let dir = out.join(format!("seed{seed}"));
        let o = deltaloop(&[
            "run",
            path.to_str().unwrap(),
            "--mode",
            "inproc",
            "--law",
            "tde-is",
            "--law",
            "tdc-is-sta",
            "--seed",
            &seed.to_string(),
            "--out",
            dir.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let sm = summary(&dir);
        let mx = |law: &str| common::max_joint_rms(&sm, law);
        logs.push((mx("tdc-is-sta") / mx("tde-is")).ln());
    }
    let by_hand = (logs.iter().sum::<f64>() / 4.0).exp();
    assert!((geo / by_hand - 1.0).abs() < 1e-12, "{geo} vs {by_hand}");
}

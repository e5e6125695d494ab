//! `vdbcook bake` end to end: manifest errors, the cache, shards and merges,
//! reports read back by real consumers (junitparser, headless Chromium), the
//! Makefile of docs/ci.md, and honest exit codes for stdout in every subcommand.

mod common;
use common::*;
// The HTML tests, in their own file (cli/tests/bake/ holds no test target of its own).
#[path = "bake/html.rs"]
mod html;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

fn scratch(tag: &str) -> Scratch {
    scratch_dir("bake", tag)
}

fn run(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_vdbcook"));
    c.args(args).current_dir(root());
    for (k, v) in env {
        c.env(k, v);
    }
    c.output().expect("run vdbcook")
}

fn err(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// `bake --json` with `args`; the exit code and the report.
fn bake(args: &[&str], env: &[(&str, &str)]) -> (Option<i32>, Value, String) {
    let mut a = vec!["bake", "--json"];
    a.extend(args);
    let o = run(&a, env);
    let v = serde_json::from_slice(&o.stdout).unwrap_or(Value::Null);
    (o.status.code(), v, err(&o))
}

fn statuses(v: &Value) -> Vec<(String, String)> {
    v["assets"].as_array().unwrap_or(&Vec::new()).iter().map(|a| (a["name"].as_str().unwrap().to_string(), a["status"].as_str().unwrap().to_string())).collect()
}

fn count(v: &Value, status: &str) -> usize {
    statuses(v).iter().filter(|(_, s)| s == status).count()
}

/// A project: copies of fixtures in `dir/src`, and a manifest of four assets.
fn project(dir: &Path) -> PathBuf {
    let src = dir.join("src");
    std::fs::create_dir_all(src.join("seq")).unwrap();
    for f in ["fog_none.vdb", "tiles.vdb", "fog_zip.vdb"] {
        std::fs::copy(root().join("fixtures").join(f), src.join(f)).unwrap();
    }
    for i in 1..=4 {
        let f = format!("smoke_{i:04}.vdb");
        std::fs::copy(root().join("fixtures/smoke_seq").join(&f), src.join("seq").join(&f)).unwrap();
    }
    let manifest = dir.join("bake.toml");
    std::fs::write(
        &manifest,
        r#"# Four assets from the fixtures.
[defaults]
format = "unorm8"

[[asset]]
name = "fog"
output = "fog.vpak"
inputs = ["src/fog_none.vdb"]

[[asset]]
name = "tiles"
output = "sub/tiles.vpak"
inputs = ["src/tiles.vdb"]
format = "f16"

[[asset]]
name = "smoke"
output = "smoke.vpak"
inputs = ["src/seq/smoke_####.vdb"]
frames = "1-4"
format = "bc4"
quality = "ultra-fast"

[[asset]]
name = "zip"
output = "zip.vpak"
inputs = ["src/fog_zip.vdb"]
clusters = 8
"#,
    )
    .unwrap();
    manifest
}

fn files_under(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            if e.path().is_dir() {
                stack.push(e.path());
            } else {
                out.push(e.path());
            }
        }
    }
    out.sort();
    out
}

#[test]
fn manifest_errors_name_file_line_and_column_and_write_nothing() {
    let dir = scratch("errors");
    let manifest = project(&dir);
    let good = std::fs::read_to_string(&manifest).unwrap();
    let cases = [
        ("unknown key", good.replace("clusters = 8", "clustres = 8"), ":28:1: unknown field `clustres`, expected one of"),
        ("wrong type", good.replace("clusters = 8", "clusters = \"eight\""), ":28:12: clusters: invalid type: string \"eight\", expected u32"),
        ("bad enum", good.replace("format = \"f16\"", "format = \"f17\""), ":14:10: format: unknown variant `f17`, expected one of"),
        ("missing file", good.replace("src/tiles.vdb", "src/nope.vdb"), ":13:11: input \"src/nope.vdb\""),
        ("missing frame", good.replace("frames = \"1-4\"", "frames = \"1-5\""), ":19:11: "),
        ("duplicate output", good.replace("zip.vpak", "./fog.vpak"), ":26:10: duplicate output \"./fog.vpak\""),
        ("duplicate name", good.replace("name = \"zip\"", "name = \"fog\""), ":25:8: duplicate asset name \"fog\""),
        ("bad value", good.replace("clusters = 8", "variance_threshold = -2.0"), ":28:22: variance_threshold: must be a number >= 0"),
        ("negative flip budget", good.replace("clusters = 8", "max_flip = -0.5"), ":28:12: max_flip: must be a finite number >= 0, not -0.5"),
        ("infinite flip budget", good.replace("clusters = 8", "max_flip = inf"), ":28:12: max_flip: must be a finite number >= 0, not inf"),
        ("not toml", good.replace("[[asset]]\nname = \"zip\"", "[[asset]\nname = \"zip\""), ":24:"),
    ];
    let out = dir.join("out");
    for (what, text, want) in cases {
        std::fs::write(&manifest, &text).unwrap();
        let o = run(&["bake", s(&manifest), "--out-dir", s(&out), "--cache", s(&dir.join("cache"))], &[]);
        let e = err(&o);
        assert_eq!(o.status.code(), Some(2), "{what}: {e}");
        assert_eq!(e.lines().count(), 1, "{what}: one line: {e}");
        let prefix = format!("vdbcook: error: {}{want}", manifest.display());
        assert!(e.starts_with(&prefix), "{what}: {e:?} should start with {prefix:?}");
        assert!(!out.exists() && !dir.join("cache").exists(), "{what}: nothing is written");
        assert!(o.stdout.is_empty(), "{what}");
    }
    std::fs::write(&manifest, &good).unwrap();
    let o = run(&["bake", s(&manifest), "--out-dir", s(&out), "--only", "nosuch"], &[]);
    assert_eq!(o.status.code(), Some(2));
    assert!(err(&o).contains("--only: no asset named \"nosuch\"") && !out.exists(), "{}", err(&o));
    let o = run(&["bake", s(&manifest), "--shard", "4/3"], &[]);
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_cache_cooks_only_what_changed() {
    let dir = scratch("cache");
    let manifest = project(&dir);
    let (m, out, cache) = (s(&manifest).to_string(), dir.join("out"), dir.join("cache"));
    let args = ["--out-dir", s(&out), "--cache", s(&cache), "--jobs", "2"];
    let mut a = vec![m.as_str()];
    a.extend(args);

    let (code, v, e) = bake(&a, &[]);
    assert_eq!(code, Some(0), "{e}");
    assert_eq!(count(&v, "baked"), 4, "{v}");
    for asset in v["assets"].as_array().unwrap() {
        let key = asset["cache_key"].as_str().unwrap();
        assert_eq!(key.len(), 32);
        let path = out.join(asset["output"].as_str().unwrap());
        assert_eq!(std::fs::metadata(&path).unwrap().len(), asset["bytes"].as_u64().unwrap());
        assert!(cache.join(format!("{key}.vpak")).is_file());
        // The key is recorded in the asset.
        let i = run(&["inspect", "--json", s(&path)], &[]);
        assert!(String::from_utf8_lossy(&i.stdout).contains(key), "{}", asset["name"]);
    }
    let first: Vec<Vec<u8>> = v["assets"].as_array().unwrap().iter().map(|a| std::fs::read(out.join(a["output"].as_str().unwrap())).unwrap()).collect();

    // Nothing changed: nothing cooked.
    let (code, v2, e) = bake(&a, &[]);
    assert_eq!((code, count(&v2, "cached")), (Some(0), 4), "{e} {v2}");
    for (x, y) in v["assets"].as_array().unwrap().iter().zip(v2["assets"].as_array().unwrap()) {
        for k in ["cache_key", "bytes", "frames", "voxel_rmse", "thumbnail", "bits_per_active_voxel"] {
            assert_eq!(x[k], y[k], "{k}");
        }
    }

    // One changed byte in one input: that asset alone.
    let fog = dir.join("src/fog_none.vdb");
    let mut bytes = std::fs::read(&fog).unwrap();
    *bytes.last_mut().unwrap() ^= 1;
    std::fs::write(&fog, &bytes).unwrap();
    let (code, v3, e) = bake(&a, &[]);
    assert_eq!(code, Some(0), "{e}");
    assert_eq!(statuses(&v3).into_iter().filter(|(_, s)| s != "cached").collect::<Vec<_>>(), [("fog".to_string(), "baked".to_string())]);
    assert_ne!(v3["assets"][0]["cache_key"], v["assets"][0]["cache_key"]);

    // A different vdbcook version: everything again, to the same bytes.
    let (code, v4, e) = bake(&a, &[("VDBCOOK_BAKE_TOOL_VERSION", "99.0.0")]);
    assert_eq!((code, count(&v4, "baked")), (Some(0), 4), "{e}");
    assert_eq!(v4["tool"], "vdbcook 99.0.0");
    let (_, v5, _) = bake(&a, &[("VDBCOOK_BAKE_TOOL_VERSION", "99.0.0")]);
    assert_eq!(count(&v5, "cached"), 4);

    // A corrupted output (its checksum fails) is baked again...
    let (_, v, _) = bake(&a, &[]);
    assert_eq!(count(&v, "cached"), 4, "back to this version's keys: all in the cache");
    let tiles = out.join("sub/tiles.vpak");
    let mut t = std::fs::read(&tiles).unwrap();
    let mid = t.len() / 2;
    t[mid] ^= 0x10;
    std::fs::write(&tiles, &t).unwrap();
    std::fs::remove_dir_all(&cache).unwrap();
    let (code, v, e) = bake(&a, &[]);
    assert_eq!(code, Some(0), "{e}");
    assert_eq!(statuses(&v).into_iter().filter(|(_, s)| s != "cached").collect::<Vec<_>>(), [("tiles".to_string(), "baked".to_string())]);
    assert_eq!(std::fs::read(&tiles).unwrap(), first[1], "the same bytes as the first bake");

    // ... and so is a corrupted cache entry; a sound one is copied.
    let key = v["assets"][1]["cache_key"].as_str().unwrap().to_string();
    let entry = cache.join(format!("{key}.vpak"));
    assert!(entry.is_file(), "the re-baked asset is stored in the cache");
    std::fs::remove_file(&tiles).unwrap();
    let (code, v, _) = bake(&a, &[]);
    assert_eq!((code, v["assets"][1]["status"].as_str()), (Some(0), Some("cached")), "copied from the cache");
    assert_eq!(std::fs::read(&tiles).unwrap(), first[1]);
    let mut c = std::fs::read(&entry).unwrap();
    let mid = c.len() / 2;
    c[mid] ^= 0x10;
    std::fs::write(&entry, &c).unwrap();
    std::fs::remove_file(&tiles).unwrap();
    let (code, v, _) = bake(&a, &[]);
    assert_eq!((code, v["assets"][1]["status"].as_str()), (Some(0), Some("baked")), "a corrupted cache entry is not used");
    assert_eq!(std::fs::read(&tiles).unwrap(), first[1]);

    // The dry run says what would happen and writes nothing.
    std::fs::remove_file(out.join("zip.vpak")).unwrap();
    let before = files_under(&dir);
    let o = run(&["bake", &m, "--out-dir", s(&out), "--dry-run", "--json"], &[]);
    assert_eq!(o.status.code(), Some(0));
    let d: Value = serde_json::from_slice(&o.stdout).unwrap();
    let actions: Vec<&str> = d["assets"].as_array().unwrap().iter().map(|a| a["action"].as_str().unwrap()).collect();
    assert_eq!(actions, ["cached", "cached", "cached", "bake"]);
    assert_eq!(files_under(&dir), before);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn shards_cover_every_asset_once_and_merge_into_the_whole() {
    let dir = scratch("shards");
    let manifest = project(&dir);
    let m = s(&manifest).to_string();
    let whole_dir = dir.join("whole");
    let (code, whole, e) = bake(&[&m, "--out-dir", s(&whole_dir), "--jobs", "2"], &[]);
    assert_eq!(code, Some(0), "{e}");
    let mut seen = Vec::new();
    let mut reports = Vec::new();
    for i in 1..=3 {
        let d = dir.join(format!("shard{i}"));
        let (code, v, e) = bake(&[&m, "--out-dir", s(&d), "--shard", &format!("{i}/3"), "--jobs", "1"], &[]);
        assert_eq!(code, Some(0), "{e}");
        for a in v["assets"].as_array().unwrap() {
            let out = a["output"].as_str().unwrap();
            assert_eq!(std::fs::read(d.join(out)).unwrap(), std::fs::read(whole_dir.join(out)).unwrap(), "{out}: the same bytes with --jobs 1 and 2, whole or sharded");
        }
        assert_eq!(v["shard"], serde_json::json!({"index": i, "count": 3}));
        seen.extend(statuses(&v).into_iter().map(|(n, _)| n));
        let r = d.join("report.json");
        assert_eq!(serde_json::from_str::<Value>(&std::fs::read_to_string(&r).unwrap()).unwrap(), v, "report.json is what --json prints");
        reports.push(r);
    }
    seen.sort();
    assert_eq!(seen, ["fog", "smoke", "tiles", "zip"], "every asset exactly once");
    let merged_dir = dir.join("merged");
    let mut args = vec!["bake", "--json", "--merge"];
    args.extend(reports.iter().map(|p| s(p)));
    args.extend(["--report-dir", s(&merged_dir)]);
    let o = run(&args, &[]);
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let merged: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(merged_dir.join("report.html").is_file() && merged_dir.join("report.xml").is_file());
    let strip = |mut v: Value| {
        v["seconds"] = Value::Null;
        v["merged"] = Value::Null;
        for a in v["assets"].as_array_mut().unwrap() {
            a["seconds"] = Value::Null;
        }
        v
    };
    assert_eq!(merged["merged"], 3);
    assert_eq!(strip(merged), strip(whole), "the merged report is the whole bake's, times aside");
    // Merging a shard twice is refused.
    let o = run(&["bake", "--merge", s(&reports[0]), s(&reports[0])], &[]);
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn plan_lists_inputs_outputs_and_keys_and_only_picks_assets() {
    let dir = scratch("plan");
    let manifest = project(&dir);
    let o = run(&["bake", s(&manifest), "--plan", "--json"], &[]);
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let p: Value = serde_json::from_slice(&o.stdout).unwrap();
    let assets = p["assets"].as_array().unwrap();
    assert_eq!(assets.len(), 4);
    assert_eq!(assets[2]["files"].as_array().unwrap().len(), 4, "the frame pattern expanded");
    assert_eq!(assets[1]["output"], "sub/tiles.vpak");
    assert_eq!(assets[1]["settings"]["format"], "f16");
    assert_eq!(assets[0]["settings"]["variance_threshold"], "0.01");
    assert_eq!(files_under(&dir).iter().filter(|f| f.extension().is_some_and(|e| e == "vpak" || e == "json")).count(), 0, "--plan writes nothing");
    let (code, v, e) = bake(&[s(&manifest), "--only", "smoke,tiles"], &[]);
    assert_eq!(code, Some(0), "{e}");
    assert_eq!(statuses(&v), [("tiles".to_string(), "baked".to_string()), ("smoke".to_string(), "baked".to_string())]);
    for a in v["assets"].as_array().unwrap() {
        let planned = assets.iter().find(|p| p["name"] == a["name"]).unwrap();
        assert_eq!(planned["cache_key"], a["cache_key"], "the plan's key is the bake's");
    }
    assert!(!dir.join("fog.vpak").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// A manifest whose assets end every way: baked, failed cook, failed gate.
fn mixed(dir: &Path, gate_only: bool) -> PathBuf {
    std::fs::write(dir.join("broken.vdb"), b"this is not an OpenVDB file").unwrap();
    let m = dir.join("mixed.toml");
    let fixtures = root().join("fixtures");
    let mut text = format!(
        "[defaults]\nviews = 2\nsize = \"32x32\"\n\n[[asset]]\nname = \"good\"\noutput = \"good.vpak\"\ninputs = [\"{f}/tiles.vdb\"]\nvalidate = true\nmax_rmse = 0.5\n\n\
[[asset]]\nname = \"strict\"\noutput = \"strict.vpak\"\ninputs = [\"{f}/smoke_seq\"]\nformat = \"bc7\"\nvalidate = true\nmax_rmse = 1e-9\n",
        f = fixtures.display()
    );
    if !gate_only {
        text += "\n[[asset]]\nname = \"broken\"\noutput = \"broken.vpak\"\ninputs = [\"broken.vdb\"]\n";
    }
    std::fs::write(&m, text).unwrap();
    m
}

#[test]
fn max_flip_gates_an_asset() {
    if !gpu_available() {
        return;
    }
    let dir = scratch("flip");
    let m = dir.join("flip.toml");
    let f = root().join("fixtures/smoke_seq");
    let text = format!(
        "[defaults]\nviews = 2\nsize = \"32x32\"\nformat = \"bc7\"\nvalidate = true\n\n\
[[asset]]\nname = \"loose\"\noutput = \"loose.vpak\"\ninputs = [\"{f}\"]\nmax_flip = 1.0\n\n\
[[asset]]\nname = \"tight\"\noutput = \"tight.vpak\"\ninputs = [\"{f}\"]\nmax_flip = 1e-9\n",
        f = f.display()
    );
    std::fs::write(&m, text).unwrap();
    let (code, v, e) = bake(&[s(&m), "--out-dir", s(&dir.join("out")), "--jobs", "1"], &[]);
    assert_eq!(code, Some(3), "only a gate failed: {e}");
    assert_eq!(statuses(&v), [("loose".into(), "baked".into()), ("tight".into(), "gate-failed".into())]);
    for (a, budget) in v["assets"].as_array().unwrap().iter().zip([1.0, 1e-9]) {
        assert_eq!(a["gate"]["max_flip"].as_f64(), Some(budget), "{a}");
        let flip = a["validation"]["image_flip"].as_f64().unwrap();
        assert!(flip > 1e-9 && flip < 1.0, "{a}");
    }
    assert!(v["assets"][1]["message"].as_str().unwrap().contains("flip"), "{v}");
    let html = std::fs::read_to_string(dir.join("out/report.html")).unwrap();
    assert!(html.contains("<th>image FLIP</th>"), "the bake report has a FLIP column");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn exit_codes_and_junit_read_back_by_junitparser() {
    if !gpu_available() {
        return;
    }
    let dir = scratch("junit");
    let m = mixed(&dir, false);
    let (code, v, e) = bake(&[s(&m), "--out-dir", s(&dir.join("out"))], &[]);
    assert_eq!(code, Some(1), "a failed cook is exit 1: {e}");
    assert_eq!(statuses(&v), [("good".into(), "baked".into()), ("strict".into(), "gate-failed".into()), ("broken".into(), "failed".into())]);
    assert!(e.contains("vdbcook: error: asset broken: ") && e.contains("vdbcook: quality gate failed: asset strict: "), "{e}");
    assert!(v["assets"][0]["validation_report"].as_str().is_some_and(|p| dir.join("out").join(p).is_file()));
    assert!(v["assets"][0]["validation"]["image_rmse"].as_f64().unwrap() > 0.0);
    assert!(!dir.join("out/broken.vpak").exists(), "no partial output");

    let has_parser = Command::new("/usr/bin/python3").args(["-c", "import junitparser"]).output().is_ok_and(|o| o.status.success());
    assert!(has_parser || !in_ci(), "CI=true but /usr/bin/python3 cannot import junitparser (scripts/test.sh installs python3-junitparser)");
    if has_parser {
        let script = r#"
import sys, json
from junitparser import JUnitXml, Failure, Skipped
xml = JUnitXml.fromfile(sys.argv[1])
out = []
for suite in xml:
    for case in suite:
        kinds = [type(r).__name__ + ":" + (r.type or "") + ":" + (r.message or "") for r in case.result]
        out.append({"name": case.name, "results": kinds, "time": case.time})
print(json.dumps({"tests": xml.tests, "failures": xml.failures, "cases": out}))
"#;
        let o = Command::new("/usr/bin/python3").args(["-c", script, s(&dir.join("out/report.xml"))]).output().unwrap();
        assert!(o.status.success(), "{}", err(&o));
        let j: Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!((j["tests"].as_u64(), j["failures"].as_u64()), (Some(3), Some(2)), "{j}");
        let cases = j["cases"].as_array().unwrap();
        assert_eq!(cases[0]["name"], "good");
        assert_eq!(cases[0]["results"].as_array().unwrap().len(), 0);
        assert!(cases[1]["results"][0].as_str().unwrap().starts_with("Failure:quality-gate:"), "{j}");
        assert!(cases[2]["results"][0].as_str().unwrap().starts_with("Failure:cook:"), "{j}");
        assert!(cases[2]["results"][0].as_str().unwrap().contains("broken.vdb"), "{j}");
    }

    // Only a gate failed: 3. Cached the second time, with the same verdict.
    let m = mixed(&dir, true);
    for status in ["gate-failed", "gate-failed"] {
        let (code, v, e) = bake(&[s(&m), "--out-dir", s(&dir.join("out2"))], &[]);
        assert_eq!(code, Some(3), "{e}");
        assert_eq!(v["assets"][1]["status"], status);
    }
    let (_, v, _) = bake(&[s(&m), "--out-dir", s(&dir.join("out2"))], &[]);
    assert_eq!(count(&v, "cached"), 1, "the passing asset is a cache hit, the gate failure is reported again");

    // --fail-fast with one job: after the failure nothing more is started.
    let m3 = dir.join("ff.toml");
    std::fs::write(
        &m3,
        format!(
            "[[asset]]\nname = \"broken\"\noutput = \"b.vpak\"\ninputs = [\"broken.vdb\"]\n\n[[asset]]\nname = \"t\"\noutput = \"t.vpak\"\ninputs = [\"{}\"]\n",
            root().join("fixtures/tiles.vdb").display()
        ),
    )
    .unwrap();
    let (code, v, _) = bake(&[s(&m3), "--out-dir", s(&dir.join("out3")), "--jobs", "1", "--fail-fast"], &[]);
    assert_eq!(code, Some(1));
    assert_eq!(statuses(&v), [("broken".into(), "failed".into()), ("t".into(), "skipped".into())]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_makefile_of_docs_ci_runs_with_make_j2() {
    let has_make = Command::new("make").arg("--version").output().is_ok_and(|o| o.status.success());
    if !has_make {
        assert!(!in_ci(), "CI=true but there is no make (scripts/test.sh installs it)");
        return;
    }
    let doc = std::fs::read_to_string(root().join("docs/ci.md")).unwrap();
    let makefile = doc.split("```make\n").nth(1).and_then(|r| r.split("\n```").next()).expect("a ```make block in docs/ci.md");
    let dir = scratch("make");
    let manifest = project(&dir);
    std::fs::write(dir.join("Makefile"), format!("{makefile}\n")).unwrap();
    let o = Command::new("make").args(["-j2", &format!("VDBCOOK={}", env!("CARGO_BIN_EXE_vdbcook"))]).current_dir(&dir).output().unwrap();
    assert!(o.status.success(), "{}\n{}", String::from_utf8_lossy(&o.stdout), err(&o));
    for f in ["fog.vpak", "sub/tiles.vpak", "smoke.vpak", "zip.vpak", "report.json", "report.html", "report.xml"] {
        assert!(dir.join("out").join(f).is_file(), "{f}");
    }
    let r: Value = serde_json::from_str(&std::fs::read_to_string(dir.join("out/report.json")).unwrap()).unwrap();
    assert_eq!(r["summary"]["assets"], 4, "{r}");
    assert_eq!(r["summary"]["baked"], 4, "{r}");
    // Up to date: make does nothing, and a second bake would cook nothing.
    let o = Command::new("make").args(["-j2", "-q", &format!("VDBCOOK={}", env!("CARGO_BIN_EXE_vdbcook"))]).current_dir(&dir).output().unwrap();
    assert_eq!(o.status.code(), Some(0), "make -q: everything is up to date: {}", err(&o));
    let (_, v, _) = bake(&[s(&manifest), "--out-dir", s(&dir.join("out"))], &[]);
    assert_eq!(count(&v, "cached"), 4);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Every subcommand that prints, with stdout on a full device: exit 1 and an error.
#[test]
fn a_full_stdout_is_an_error_in_every_subcommand() {
    if !Path::new("/dev/full").exists() {
        assert!(!in_ci() || !cfg!(target_os = "linux"), "CI=true on Linux but no /dev/full");
        return;
    }
    let dir = scratch("full");
    let manifest = project(&dir);
    let asset = dir.join("a.vpak");
    let vdb = dir.join("a.vdb");
    let png = dir.join("a.png");
    let mut cases: Vec<Vec<String>> = vec![
        vec!["inspect".into(), "fixtures/tiles.vdb".into()],
        vec!["inspect".into(), "--json".into(), "fixtures/tiles.vdb".into()],
        vec!["cook".into(), "fixtures/tiles.vdb".into(), "-o".into(), s(&asset).into()],
        vec!["cook".into(), "--json".into(), "fixtures/tiles.vdb".into(), "-o".into(), s(&asset).into(), "--force".into()],
        vec!["inspect".into(), s(&asset).into()],
        vec!["inspect".into(), "--json".into(), s(&asset).into()],
        vec!["unpack".into(), s(&asset).into(), "--frame".into(), "0".into(), "-o".into(), s(&vdb).into()],
        vec!["diff".into(), "fixtures/tiles.vdb".into(), "fixtures/tiles.vdb".into()],
        vec!["diff".into(), "--json".into(), "fixtures/tiles.vdb".into(), "fixtures/tiles.vdb".into()],
        vec!["bake".into(), s(&manifest).into(), "--plan".into()],
        vec!["bake".into(), s(&manifest).into(), "--plan".into(), "--json".into()],
        vec!["bake".into(), s(&manifest).into(), "--dry-run".into()],
        vec!["bake".into(), s(&manifest).into(), "--only".into(), "tiles".into()],
        vec!["bake".into(), s(&manifest).into(), "--only".into(), "tiles".into(), "--json".into()],
        vec!["bake".into(), "--merge".into(), s(&dir.join("report.json")).into(), "--report-dir".into(), s(&dir.join("m")).into()],
        vec!["--help".into()],
    ];
    if gpu_available() {
        cases.push(vec!["validate".into(), s(&asset).into(), "--source".into(), "fixtures/tiles.vdb".into(), "--views".into(), "1".into(), "--size".into(), "16x16".into()]);
        cases.push(vec!["validate".into(), "--json".into(), s(&asset).into(), "--source".into(), "fixtures/tiles.vdb".into(), "--views".into(), "1".into(), "--size".into(), "16x16".into()]);
        cases.push(vec!["render".into(), s(&asset).into(), "-o".into(), s(&png).into(), "--size".into(), "16x16".into()]);
    }
    for args in &cases {
        let full = std::fs::OpenOptions::new().write(true).open("/dev/full").unwrap();
        let o = Command::new(env!("CARGO_BIN_EXE_vdbcook")).args(args).current_dir(root()).stdout(full).output().unwrap();
        let e = err(&o);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {e}");
        assert!(e.contains("vdbcook: error: cannot write to stdout: No space left on device"), "{args:?}: {e}");
        assert_eq!(e.matches("No space left").count(), 1, "said once: {e}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A reader that goes away (`| head -1`) ends the output quietly, with exit 0.
#[test]
fn a_closed_pipe_ends_the_output_quietly() {
    let dir = scratch("pipe");
    let manifest = project(&dir);
    let asset = dir.join("a.vpak");
    assert!(vdbcook(&["cook", "-q", "fixtures/smoke_seq", "-o", s(&asset)]).status.success());
    let cases: Vec<Vec<&str>> = vec![
        vec!["inspect", "fixtures/multi_grid.vdb", "fixtures/tiles.vdb"],
        vec!["inspect", "--json", "fixtures/multi_grid.vdb"],
        vec!["inspect", s(&asset)],
        vec!["diff", "--json", "fixtures/tiles.vdb", "fixtures/tiles.vdb"],
        vec!["bake", s(&manifest), "--plan", "--json"],
        vec!["bake", s(&manifest), "--only", "tiles", "--json"],
    ];
    for args in &cases {
        // The reader is gone before the first write.
        let mut child = Command::new(env!("CARGO_BIN_EXE_vdbcook")).args(args).current_dir(root()).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
        drop(child.stdout.take());
        let o = child.wait_with_output().unwrap();
        assert_eq!(o.status.code(), Some(0), "{args:?}: {}", err(&o));
        assert!(o.stderr.is_empty(), "{args:?}: {}", err(&o));
        // And through a real `| head -1`.
        let line = format!("'{}' {} | head -1 >/dev/null; echo \"${{PIPESTATUS[0]}}\"", env!("CARGO_BIN_EXE_vdbcook"), args.iter().map(|a| format!("'{a}'")).collect::<Vec<_>>().join(" "));
        let o = Command::new("bash").args(["-c", &line]).current_dir(root()).output().unwrap();
        assert_eq!(String::from_utf8_lossy(&o.stdout).trim(), "0", "{args:?}: {}", err(&o));
        assert!(!err(&o).contains("error"), "{args:?}: {}", err(&o));
    }
    // The exit code of the work stands: a bake with a failed asset is still 1.
    std::fs::write(dir.join("broken.vdb"), b"not a vdb").unwrap();
    let m = dir.join("broken.toml");
    std::fs::write(&m, "[[asset]]\nname = \"b\"\noutput = \"b.vpak\"\ninputs = [\"broken.vdb\"]\n").unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_vdbcook")).args(["bake", "--json", s(&m)]).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    drop(child.stdout.take());
    let o = child.wait_with_output().unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", err(&o));
    assert_eq!(err(&o).lines().count(), 1, "only the asset's error: {}", err(&o));
    let _ = std::fs::remove_dir_all(&dir);
}

/// docs/bake-json.md against real output, both ways: every documented key is
/// there and every key there is documented.
#[test]
fn the_json_follows_the_documented_schema() {
    if !gpu_available() {
        return;
    }
    let dir = scratch("schema");
    let m = mixed(&dir, false);
    let (_, v, e) = bake(&[s(&m), "--out-dir", s(&dir.join("out"))], &[]);
    assert_eq!(v["assets"].as_array().map(Vec::len), Some(3), "{e}");
    let doc = std::fs::read_to_string(root().join("docs/bake-json.md")).unwrap();
    let keys = |name: &str| doc_section(&doc, name);
    assert_documented(&v, &keys("Top level"), "top level");
    assert_documented(&v["summary"], &keys("Summary"), "summary");
    for a in v["assets"].as_array().unwrap() {
        assert_documented(a, &keys("Asset entries"), "asset");
        assert_documented(&a["gate"], &keys("Gate"), "gate");
        if a["validation"].is_object() {
            assert_documented(&a["validation"], &keys("Validation"), "validation");
        }
        assert!(["baked", "cached", "failed", "gate-failed", "skipped"].contains(&a["status"].as_str().unwrap()));
    }
    assert!(v["assets"].as_array().unwrap().iter().any(|a| a["validation"].is_object()));
    let _ = std::fs::remove_dir_all(&dir);
}

/// A one-asset manifest in `dir` writing `output` from the tiles fixture.
fn one_asset(dir: &Path, output: &str) -> PathBuf {
    let m = dir.join("one.toml");
    let text = format!("[[asset]]\nname = \"t\"\noutput = \"{output}\"\ninputs = [\"{}\"]\nformat = \"unorm8\"\n", root().join("fixtures/tiles.vdb").display());
    std::fs::write(&m, text).unwrap();
    m
}

#[test]
fn a_bake_writes_only_inside_its_out_dir() {
    let dir = scratch("outside");
    let (out, elsewhere) = (dir.join("out"), dir.join("elsewhere"));
    std::fs::create_dir_all(&elsewhere).unwrap();
    let victim = elsewhere.join("victim.txt");
    std::fs::write(&victim, "precious").unwrap();
    std::fs::create_dir_all(&out).unwrap();
    #[cfg(unix)]
    std::os::unix::fs::symlink(&elsewhere, out.join("link")).unwrap();
    let mut cases = vec![(s(&victim).to_string(), "is an absolute path"), ("../escape.vpak".into(), "through '..'"), ("sub/../../escape.vpak".into(), "through '..'")];
    if cfg!(unix) {
        cases.push(("link/escape.vpak".into(), "through a symbolic link"));
    }
    let cache = dir.join("cache");
    for (output, says) in &cases {
        let m = one_asset(&dir, output);
        for mode in [&[][..], &["--plan"][..], &["--dry-run"][..]] {
            let mut args = vec!["bake", s(&m), "--out-dir", s(&out), "--cache", s(&cache)];
            args.extend(mode);
            let o = run(&args, &[]);
            let e = err(&o);
            assert_eq!(o.status.code(), Some(2), "{output} {mode:?}: {e}");
            assert!(e.starts_with(&format!("vdbcook: error: {}:3:10: output \"{output}\"", m.display())) && e.contains(says) && e.lines().count() == 1, "{output}: {e}");
        }
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious");
        assert!(!dir.join("escape.vpak").exists() && !elsewhere.join("escape.vpak").exists() && !cache.exists(), "{output}: nothing written");
        assert_eq!(std::fs::read_dir(&out).unwrap().count(), usize::from(cfg!(unix)), "{output}: nothing but the link in {}", out.display());
    }
    // --allow-outside: the person running the bake says so. Not over a text file without --force.
    let m = one_asset(&dir, "../escape.vpak");
    let (code, v, e) = bake(&[s(&m), "--out-dir", s(&out), "--allow-outside"], &[]);
    assert_eq!((code, count(&v, "baked")), (Some(0), 1), "{e}");
    assert!(std::fs::read(dir.join("escape.vpak")).unwrap().starts_with(b"VPAK"));
    let m = one_asset(&dir, s(&victim));
    let (code, v, e) = bake(&[s(&m), "--out-dir", s(&out), "--allow-outside"], &[]);
    assert_eq!((code, count(&v, "failed")), (Some(1), 1), "{e}");
    assert!(e.contains(&format!("{} already exists and is not a .vpak asset", victim.display())) && e.contains("--force"), "{e}");
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn only_a_vpak_or_a_report_is_replaced_without_force() {
    let dir = scratch("replace");
    let manifest = project(&dir);
    let out = dir.join("out");
    std::fs::create_dir_all(out.join("sub")).unwrap();
    // fog.vpak is someone's text file; sub/tiles.vpak an asset of other inputs.
    std::fs::write(out.join("fog.vpak"), "not an asset").unwrap();
    assert!(vdbcook(&["cook", "-q", "fixtures/smoke_seq", "-o", s(&out.join("sub/tiles.vpak"))]).status.success());
    let (code, v, e) = bake(&[s(&manifest), "--out-dir", s(&out), "--jobs", "2"], &[]);
    assert_eq!(code, Some(1), "{e}");
    assert_eq!(statuses(&v), [("fog", "failed"), ("tiles", "baked"), ("smoke", "baked"), ("zip", "baked")].map(|(n, s)| (n.to_string(), s.to_string())));
    assert_eq!(e.lines().count(), 1, "{e}");
    assert!(e.contains(&format!("asset fog: {} already exists and is not a .vpak asset (left as it is; --force replaces it)", out.join("fog.vpak").display())), "{e}");
    assert_eq!(std::fs::read_to_string(out.join("fog.vpak")).unwrap(), "not an asset", "survives the bake");
    let tiles = v["assets"][1]["cache_key"].as_str().unwrap();
    assert!(String::from_utf8_lossy(&vdbcook(&["inspect", "--json", s(&out.join("sub/tiles.vpak"))]).stdout).contains(tiles), "the old .vpak is replaced");
    let (code, v, e) = bake(&[s(&manifest), "--out-dir", s(&out), "--force"], &[]);
    assert_eq!((code, count(&v, "baked"), count(&v, "cached")), (Some(0), 1, 3), "{e}");
    assert!(std::fs::read(out.join("fog.vpak")).unwrap().starts_with(b"VPAK"));

    // The report and cache directories: checked before anything is baked (exit 2).
    let page = dir.join("reports/report.html");
    std::fs::create_dir_all(page.parent().unwrap()).unwrap();
    std::fs::write(&page, "<html>my page</html>").unwrap();
    let not_dir = dir.join("file");
    std::fs::write(&not_dir, "x").unwrap();
    let fresh = dir.join("fresh");
    let cases: [(&[&str], String); 4] = [
        (&["--report-dir", s(page.parent().unwrap())], format!("{} already exists and is not a vdbcook bake report", page.display())),
        (&["--cache", s(&not_dir)], format!("--cache {}: not a directory", not_dir.display())),
        (&["--report-dir", s(&not_dir)], format!("--report-dir {}: not a directory", not_dir.display())),
        (&["--out-dir", s(&not_dir)], format!("--out-dir {}: not a directory", not_dir.display())),
    ];
    for (extra, want) in cases {
        let mut args = vec!["bake", s(&manifest)];
        if extra[0] != "--out-dir" {
            args.extend(["--out-dir", s(&fresh)]);
        }
        args.extend(extra);
        let o = run(&args, &[]);
        assert_eq!(o.status.code(), Some(2), "{extra:?}: {}", err(&o));
        assert!(err(&o).contains(&want) && err(&o).lines().count() == 1, "{extra:?}: {}", err(&o));
        assert!(!fresh.exists(), "{extra:?}: nothing baked");
    }
    assert_eq!(std::fs::read_to_string(&page).unwrap(), "<html>my page</html>");
    // A report directory outside --out-dir is the caller's choice; its own earlier reports are replaced.
    for _ in 0..2 {
        let (code, _, e) = bake(&[s(&manifest), "--out-dir", s(&out), "--report-dir", s(&dir.join("elsewhere"))], &[]);
        assert_eq!(code, Some(0), "{e}");
    }
    let (code, _, e) = bake(&[s(&manifest), "--out-dir", s(&out), "--report-dir", s(page.parent().unwrap()), "--force"], &[]);
    assert_eq!(code, Some(0), "{e}");
    assert!(std::fs::read_to_string(&page).unwrap().contains("vdbcook bake"));
    let _ = std::fs::remove_dir_all(&dir);
}

//! Several grids in one asset (`cook --grids`, `--group`), end to end: the
//! command line, inspect, validate and the fire render.

mod common;
use common::*;
use std::path::Path;

fn scratch(tag: &str) -> Scratch {
    scratch_dir("channels", tag)
}

fn sample(rel: &str) -> Option<String> {
    shared_samples().map(|p| p.join(rel).to_string_lossy().into_owned())
}

#[test]
fn a_missing_grid_or_a_bad_group_is_a_usage_error_that_says_what_there_is() {
    let Some(w) = sample("waveletturbulence") else { return };
    let dir = scratch("usage");
    let out = dir.join("x.vpak");
    let r = vdbcook(&["cook", "-q", "--grids", "density,smoke", "-o", s(&out), &w]);
    assert_eq!(r.status.code(), Some(2));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("\"smoke\"") && err.contains("density") && err.contains("temperature") && err.contains("fluid_data_0150.vdb"), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(!out.exists());
    for (group, want) in [("flames=bc7", "not a channel"), ("density=bc9", "CHANNELS=FORMAT"), ("=bc7", "CHANNELS=FORMAT")] {
        let r = vdbcook(&["cook", "-q", "--grids", "density,temperature", "--group", group, "-o", s(&out), &w]);
        assert_eq!(r.status.code(), Some(2), "{group}");
        assert!(String::from_utf8_lossy(&r.stderr).contains(want), "{group}: {}", String::from_utf8_lossy(&r.stderr));
    }
    let r = vdbcook(&["cook", "-q", "--grid", "density", "--grids", "density", "-o", s(&out), &w]);
    assert_eq!(r.status.code(), Some(2), "--grid and --grids conflict");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn grids_all_cooks_every_float_grid_into_one_tree() {
    let Some(w) = sample("waveletturbulence") else { return };
    let dir = scratch("all");
    let out = dir.join("w.vpak");
    let cooked: serde_json::Value = serde_json::from_slice(&ok(vdbcook(&["cook", "--json", "--grids", "all", "--format", "unorm8", "-o", s(&out), &w])).stdout).unwrap();
    let f = inspect(&out);
    let names: Vec<&str> = f["channels"].as_array().unwrap().iter().map(|c| c["name"].as_str().unwrap()).collect();
    for want in ["density", "shadow", "temperature", "flame"] {
        assert!(names.contains(&want), "{names:?}");
    }
    assert_eq!(cooked["channels"].as_array().unwrap().len(), names.len());
    // A texture per channel, each storing its own distinct bricks: the all-zero
    // flame is one brick, reached through a brick table.
    let planes = f["planes"].as_array().unwrap();
    assert_eq!(planes.len(), names.len());
    let flame = &planes[f["channels"].as_array().unwrap().iter().find(|c| c["name"] == "flame").unwrap()["plane"].as_u64().unwrap() as usize];
    assert_eq!((flame["bricks"].as_u64(), flame["brick_table"].as_bool()), (Some(1), Some(true)), "{flame}");
    // A group packs four scalar channels into one RGBA texture.
    let grouped = dir.join("g.vpak");
    ok(vdbcook(&["cook", "-q", "--grids", "all", "--format", "unorm8", "--group", "density,shadow,temperature,flame=unorm8", "-o", s(&grouped), &w]));
    assert!(inspect(&grouped)["planes"].as_array().unwrap().iter().any(|p| p["lanes"] == 4));
    // One tree: as many leaves as the density alone (every grid shares its leaves here).
    let one = dir.join("d.vpak");
    let d: serde_json::Value = serde_json::from_slice(&ok(vdbcook(&["cook", "--json", "--format", "unorm8", "-o", s(&one), &w])).stdout).unwrap();
    assert_eq!(cooked["bricks"], d["bricks"]);
    assert_eq!(cooked["l1_nodes"], d["l1_nodes"]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn embergen_fire_has_an_empty_first_frame_and_renders_as_fire() {
    let Some(e) = sample("vfx-toolkit-embergen") else { return };
    let dir = scratch("fire");
    let out = dir.join("fire.vpak");
    let files: Vec<String> = (0..4).map(|k| format!("{e}/embergen_fire_a_{k}.vdb")).collect();
    let mut args = vec!["cook", "-q", "--grids", "temperature,flames", "--format", "bc7", "-o", s(&out)];
    args.extend(files.iter().map(String::as_str));
    ok(vdbcook(&args));
    let f = inspect(&out);
    assert_eq!(f["frame_info"][0]["active_voxels"], 0, "frame 0 of the EmberGen pack is empty");
    assert!(f["frame_info"][3]["active_voxels"].as_u64().unwrap() > 40_000);
    if !gpu_available() {
        return;
    }
    // validate: per-channel voxel figures, and an RGB report whose images glow.
    let report = dir.join("report");
    let mut args = vec!["validate", s(&out), "--views", "2", "--size", "96x96", "--json", "--report", s(&report), "--source"];
    args.extend(files.iter().map(String::as_str));
    let r = vdbcook(&args);
    assert_eq!(r.status.code(), Some(0), "{}", String::from_utf8_lossy(&r.stderr));
    let v: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    let ch = v["voxel_channels"].as_array().unwrap();
    assert_eq!(ch.iter().map(|c| c["name"].as_str().unwrap()).collect::<Vec<_>>(), ["temperature", "flames"]);
    assert!(ch.iter().all(|c| c["rmse"].as_f64().unwrap() > 0.0 && c["format"] == "bc7"));
    assert_eq!(v["shown"], "flames", "without density, flames give extinction");
    // The rendered fire is orange: red above green above blue where it glows.
    let png = dir.join("fire.png");
    ok(vdbcook(&["render", s(&out), "--frame", "3", "--size", "96x96", "-o", s(&png)]));
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&png).unwrap()));
    let mut reader = dec.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb);
    let lit: Vec<&[u8]> = buf[..info.buffer_size()].chunks(3).filter(|p| p[0] > 40).collect();
    assert!(lit.len() > 50, "the fire shows ({} lit pixels)", lit.len());
    let (r, g, b) = lit.iter().fold((0u64, 0u64, 0u64), |a, p| (a.0 + u64::from(p[0]), a.1 + u64::from(p[1]), a.2 + u64::from(p[2])));
    assert!(r > g && g > b, "fire is red > green > blue on average: {r} {g} {b}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// (grid name in the unpacked file, its values by coordinate as OpenVDB reads them).
type ReadBack = std::collections::HashMap<String, std::collections::HashMap<[i32; 3], Vec<f64>>>;

/// Every grid of an unpacked file as OpenVDB reads it: scalar and vec3 values by coordinate.
fn openvdb_grids(file: &Path, dir: &Path) -> ReadBack {
    let (d1, d3) = (dir.join("d1.bin"), dir.join("d3.bin"));
    let json = run_oracle(file, &["--voxels", s(&d1), "--vec3-voxels", s(&d3)]).expect("OpenVDB reads the unpacked file");
    let names: Vec<String> = json["grids"].as_array().unwrap().iter().map(|g| g["name"].as_str().unwrap().to_string()).collect();
    let mut out: ReadBack = ReadBack::new();
    for (g, c, v) in read_dump::<1>(&d1).voxels {
        out.entry(names[g as usize].clone()).or_default().insert(c, v.to_vec());
    }
    for (g, c, v) in read_dump::<3>(&d3).voxels {
        out.entry(names[g as usize].clone()).or_default().insert(c, v.to_vec());
    }
    out
}

#[test]
fn every_sample_with_several_grids_round_trips_through_openvdb() {
    let Some(root) = shared_samples() else { return };
    if !oracle_available() {
        return;
    }
    // (files of one sequence, format): every sample with two or more float or
    // vec3 grids, each bound of the checks met by one of them.
    let seq = |dir: &str, names: &[&str]| names.iter().map(|n| root.join(dir).join(n).to_string_lossy().into_owned()).collect::<Vec<_>>();
    let cases = [
        (seq("waveletturbulence", &["fluid_data_0150.vdb", "fluid_data_0151.vdb"]), "f32"),
        (seq("plasmadxr", &["fluid_data_0001.vdb"]), "f16"),
        (seq("c42", &["fluid_data_0001.vdb"]), "unorm8"),
        (seq("vfx-toolkit-embergen", &["embergen_fire_a_1.vdb", "embergen_fire_a_2.vdb"]), "unorm8"),
        (seq("arnold-usd", &["grids.vdb"]), "f32"),
        (seq("waveletturbulence", &["fluid_data_0153.vdb"]), "f16"),
    ];
    let results = par_map(&cases, |(files, format)| -> Result<usize, String> {
        let dir = scratch(&format!("rt-{}-{format}", Path::new(&files[0]).parent().unwrap().file_name().unwrap().to_string_lossy()));
        let asset = dir.join("a.vpak");
        let mut args = vec!["cook", "-q", "--grids", "all", "--format", format, "-o", s(&asset)];
        args.extend(files.iter().map(String::as_str));
        let r = vdbcook(&args);
        if !r.status.success() {
            return Err(format!("{files:?}: cook failed: {}", String::from_utf8_lossy(&r.stderr)));
        }
        let meta = inspect(&asset);
        let channels = meta["channels"].as_array().unwrap().clone();
        let mut compared = 0;
        for (frame, file) in files.iter().enumerate() {
            let out = dir.join(format!("f{frame}.vdb"));
            ok(vdbcook(&["unpack", s(&asset), "--frame", &frame.to_string(), "-o", s(&out)]));
            let back = openvdb_grids(&out, &dir);
            let src = vdbcook_vdb::open(Path::new(file)).unwrap();
            for ch in &channels {
                let (name, grid) = (ch["name"].as_str().unwrap(), ch["grid"].as_str().unwrap());
                let component = ch["component"].as_u64().map(|c| c as usize);
                let Some(gi) = src.grids.iter().position(|g| g.name == grid) else { continue };
                let parts = src.read_channels(gi).map_err(|e| e.to_string())?;
                let g = &parts[component.unwrap_or(0)];
                let range = [ch["value_range"][0].as_f64().unwrap(), ch["value_range"][1].as_f64().unwrap()];
                let bound = |v: f64| match *format {
                    "f32" => 0.0,
                    "f16" => v.abs() * 2f64.powi(-11) + 1e-7,
                    _ => (range[1] - range[0]) / 255.0 * 0.5 + 1e-6,
                };
                let theirs = back.get(grid).ok_or_else(|| format!("{file}: OpenVDB finds no grid {grid} in the unpacked file"))?;
                for l in &g.leaves {
                    for i in l.mask.iter_on() {
                        let (x, y, z) = vdbcook_grid::leaf_local(i);
                        let c = [l.origin.x + x, l.origin.y + y, l.origin.z + z];
                        let v = theirs.get(&c).map(|v| v[component.unwrap_or(0)]).ok_or_else(|| format!("{file} {name}: voxel {c:?} is not active in the unpacked grid"))?;
                        let want = f64::from(l.values[i]);
                        if (v - want).abs() > bound(want) {
                            return Err(format!("{file} {name} ({format}): voxel {c:?}: {v} read back, {want} in the source"));
                        }
                        compared += 1;
                    }
                }
            }
        }
        let _ = std::fs::remove_dir_all(&dir);
        Ok(compared)
    });
    let mut total = 0;
    for r in results {
        total += r.unwrap();
    }
    assert!(total > 1_000_000, "{total} values compared");
}

#[test]
fn an_asset_with_more_textures_than_the_renderer_binds_validates_its_shown_channels() {
    // c42 has 27 scalar and vector channels, a texture each: the renderer
    // binds the textures of the channels its image shows (density,
    // temperature, flame), not all 27.
    let Some(c) = sample("c42") else { return };
    if !gpu_available() {
        return;
    }
    let dir = scratch("many");
    let out = dir.join("c.vpak");
    let src = format!("{c}/fluid_data_0001.vdb");
    ok(vdbcook(&["cook", "-q", "--grids", "all", "--format", "f16", "-o", s(&out), &src]));
    assert!(inspect(&out)["planes"].as_array().unwrap().len() > vdbcook_validate::MAX_TEXTURES);
    // 64 pixels: at 24 the small plume falls between pixel centres, a blank picture (an error).
    let r = vdbcook(&["validate", s(&out), "--views", "1", "--size", "64x64", "--json", "--source", &src]);
    assert_eq!(r.status.code(), Some(0), "{}", String::from_utf8_lossy(&r.stderr));
    let v: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    // f16 of a half-float file: exact, so the images agree.
    assert_eq!(v["worst"]["rmse"].as_f64(), Some(0.0), "{v}");
    let _ = std::fs::remove_dir_all(&dir);
}

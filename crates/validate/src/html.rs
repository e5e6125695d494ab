//! The comparison's report: report.json, PNGs of the worst views and a
//! self-contained report.html.

use crate::compare::{Kept, LevelRun};
use crate::flip::DEFAULT_PPD;
use crate::report;
use std::path::Path;

type Result<T> = std::result::Result<T, Box<dyn std::error::Error + Send + Sync>>;

/// Writes a view's four images into the report directory as
/// `{stem}_reference.png`, `_asset`, `_error` (|difference| over `scale`) and
/// `_flip`; returns their figures (inline image and caption) for the HTML.
fn view_figures(write: &dyn Fn(&str, &[u8]) -> Result<()>, stem: &str, k: &Kept, format: &str, scale: f32) -> Result<Vec<String>> {
    let max_flip = k.flip.errors.iter().copied().fold(0.0f32, f32::max);
    [
        ("reference", report::png_rgb(&k.reference), "reference (lossless)".to_string()),
        ("asset", report::png_rgb(&k.asset), format!("asset ({})", report::esc(format))),
        ("error", report::png_heat(&k.reference, &k.asset, scale), format!("|difference|, full scale {scale:.2e}")),
        ("flip", report::png_flip(&k.flip), format!("FLIP error map (magma, 0 to 1): mean {:.4}, max {max_flip:.3}", k.shot.flip)),
    ]
    .into_iter()
    .map(|(kind, png, caption)| {
        write(&format!("{stem}_{kind}.png"), &png)?;
        Ok(format!("<figure><img src='data:image/png;base64,{}'><figcaption>{caption}</figcaption></figure>", report::base64(&png)))
    })
    .collect()
}

/// report.json, the PNGs and report.html: the summary (a row per level), the
/// first level's per-frame plot and worst views, and with several levels the
/// first level's worst view at every level, side by side.
pub(crate) fn write_report(dir: &Path, doc: &serde_json::Value, runs: &[LevelRun], gated: bool) -> Result<()> {
    let first = runs.first().ok_or("no level to report")?;
    let (format, name) = (doc["format"].as_str().unwrap_or(""), doc["asset"].as_str().unwrap_or(""));
    std::fs::create_dir_all(dir)?;
    let write = |file: &str, bytes: &[u8]| vdbcook_vpak::write_atomic(&dir.join(file), bytes, true).map_err(|e| -> Box<dyn std::error::Error + Send + Sync> { Box::new(e) });
    write("report.json", format!("{}\n", serde_json::to_string_pretty(doc).unwrap_or_default()).as_bytes())?;
    // "at level k" in headings only when there are levels to tell apart.
    let at = |lod: u32| if runs.len() > 1 { format!(", level {lod}") } else { String::new() };
    let mut figures = String::new();
    for k in &first.kept {
        let s = &k.shot;
        let figs = view_figures(&write, &format!("frame{}_view{}", s.frame, s.view), k, format, (s.metrics.max_error as f32).max(1e-6))?;
        figures += &format!(
            "<h3>frame {} view {}: rmse {:.3e}, psnr {:.1} dB, max {:.3e}, FLIP {:.4}, coverage {:.1} %</h3><div class='row'>{}</div>",
            s.frame,
            s.view,
            s.metrics.rmse,
            s.metrics.psnr,
            s.metrics.max_error,
            s.flip,
            100.0 * s.coverage,
            figs.concat()
        );
    }
    let side = if runs.len() > 1 { levels_side_by_side(&write, runs, format)? } else { String::new() };
    // Worst view per frame: RMSE and FLIP; and the emptiest view's coverage.
    let mut per_frame: Vec<(usize, f64, f64, f64)> = Vec::new();
    for s in &first.figures.shots {
        match per_frame.iter_mut().find(|e| e.0 == s.frame) {
            Some(e) => (e.1, e.2, e.3) = (e.1.max(s.metrics.rmse), e.2.max(s.flip), e.3.min(s.coverage)),
            None => per_frame.push((s.frame, s.metrics.rmse, s.flip, s.coverage)),
        }
    }
    let rows: String = per_frame.iter().map(|(f, r, fl, c)| format!("<tr><td>{f}</td><td>{r:.4e}</td><td>{fl:.4}</td><td>{:.1} %</td></tr>", 100.0 * c)).collect();
    // A figure of the JSON as people read it: 4 significant digits (RMSE) or 2 decimals (dB).
    let show = |x: &serde_json::Value, sci: bool| match x {
        serde_json::Value::Number(n) => n.as_f64().map(|x| if sci { format!("{x:.4e}") } else { format!("{x:.2}") }).unwrap_or_default(),
        serde_json::Value::String(s) if s == "Infinity" => "∞ (exact)".into(),
        serde_json::Value::String(s) => s.clone(),
        _ => "–".into(),
    };
    let levels = doc["levels"].as_array().map_or(&[][..], |v| &v[..]);
    let summary: String = runs
        .iter()
        .zip(levels)
        .map(|(r, l)| {
            let gate = match (gated, &r.figures.gate_failure) {
                (false, _) => String::new(),
                (true, None) => "<td class='pass'>pass</td>".into(),
                (true, Some(_)) => "<td class='fail'>fail</td>".into(),
            };
            format!(
                "<tr><td>{}</td><td>{}×</td><td>{g}</td><td>{f}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td>{gate}</tr>",
                r.figures.lod,
                1u64 << r.figures.lod,
                show(&l["worst"]["rmse"], true),
                show(&l["worst"]["psnr"], false),
                l["worst_flip"]["flip"].as_f64().map(|x| format!("{x:.4}")).unwrap_or_default(),
                show(&l["voxel"]["rmse"], true),
                show(&l["voxel"]["psnr"], false),
                g = report::esc(&format!("{} ({})", doc["shown"].as_str().unwrap_or(""), doc["model"].as_str().unwrap_or(""))),
                f = report::esc(format),
            )
        })
        .collect();
    let html = format!(
        "<!doctype html><html><head><meta charset='utf-8'><title>vdbcook validation: {n}</title>\
<style>body{{font-family:sans-serif;margin:2em;color:#222}}table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:4px 8px;text-align:right}}\
.row{{display:flex;gap:1em}}figure{{margin:0}}figcaption{{font-size:small;max-width:300px}}img{{image-rendering:pixelated;max-width:300px;min-width:160px}}\
td.pass{{color:#060}}td.fail{{color:#b00;font-weight:bold}}table.levels td,table.levels th{{text-align:left;vertical-align:top}}table.levels th{{font-weight:normal;font-size:small}}</style></head><body>\
<h1>vdbcook validation</h1><p>{n}, adapter {ad}</p>\
<table><tr><th>level</th><th>voxel size (source voxels)</th><th>model</th><th>format</th><th>worst image RMSE</th><th>worst PSNR (dB)</th><th>worst FLIP</th><th>voxel RMSE</th><th>voxel PSNR (dB)</th>{gh}</tr>{summary}</table>\
<p>FLIP: NVIDIA's perceptual error (LDR-FLIP, mean over the image, 0 to 1) at {ppd} pixels per degree, on the 8-bit sRGB images shown here.{lv}</p>\
<h2>Per-frame error (worst view{l0})</h2>{plot}<table><tr><th>frame</th><th>RMSE</th><th>FLIP</th><th>coverage (emptiest view)</th></tr>{rows}</table>{side}<h2>Worst views{l0}</h2>{figures}</body></html>",
        n = report::esc(name),
        ad = report::esc(doc["adapter"].as_str().unwrap_or("")),
        gh = if gated { "<th>gate</th>" } else { "" },
        ppd = DEFAULT_PPD,
        lv = if runs.len() > 1 { " Level k has voxels 2<sup>k</sup> times the source's, and is compared with the source filtered to it." } else { "" },
        l0 = at(first.figures.lod),
        plot = report::svg_plot(&per_frame.iter().map(|p| p.1).collect::<Vec<_>>(), &per_frame.iter().map(|p| p.0).collect::<Vec<_>>(), "image RMSE per frame"),
    );
    write("report.html", html.as_bytes())
}

/// The report's "Levels side by side": the first level's worst view at every
/// level, a column per level (its PNGs named `level{k}_frame{f}_view{v}_*.png`)
/// and a row per kind of image.
fn levels_side_by_side(write: &dyn Fn(&str, &[u8]) -> Result<()>, runs: &[LevelRun], format: &str) -> Result<String> {
    let views: Vec<(&LevelRun, &Kept)> = runs.iter().filter_map(|r| r.kept.first().map(|k| (r, k))).collect();
    let Some((first, focus)) = views.first() else { return Ok(String::new()) };
    // One scale for every level's |difference|, so that the levels compare by eye.
    let scale = views.iter().map(|(_, k)| k.shot.metrics.max_error as f32).fold(1e-6, f32::max);
    let mut head = String::new();
    let mut cols = Vec::new();
    for (r, k) in &views {
        let s = &k.shot;
        cols.push(view_figures(write, &format!("level{}_frame{}_view{}", r.figures.lod, s.frame, s.view), k, format, scale)?);
        let w = r.figures.worst.map_or(String::new(), |w| format!("<br>level's worst image: rmse {:.3e}, FLIP {:.4}", w.rmse, w.flip));
        head += &format!("<th><b>level {}</b> (voxels {}×)<br>this view: rmse {:.3e}, psnr {:.1} dB, FLIP {:.4}{w}</th>", r.figures.lod, 1u64 << r.figures.lod, s.metrics.rmse, s.metrics.psnr, s.flip);
    }
    let body: String =
        (0..cols.first().map_or(0, Vec::len)).map(|i| format!("<tr>{}</tr>", cols.iter().map(|c| format!("<td>{}</td>", c.get(i).map_or("", String::as_str))).collect::<String>())).collect();
    Ok(format!(
        "<h2>Levels side by side</h2><p>Frame {} view {} (the worst view of level {}) at every level, each against the source filtered to that level; \
the |difference| maps share one scale (full scale {scale:.2e}).</p><table class='levels'><tr>{head}</tr>{body}</table>",
        focus.shot.frame, focus.shot.view, first.figures.lod
    ))
}

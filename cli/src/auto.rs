//! `vdbcook cook --auto`: every format cooked from one read of the frames,
//! validated smallest file first; the first whose images meet the gate is
//! written.

use crate::cook::{cook_formats, json_text, summary_json, summary_text, CookArgs, CookJob, Cooked};
use crate::progress::Bars;
use crate::validate::{GpuArgs, ValidateArgs};
use crate::{exit, Usage};
use anyhow::{anyhow, Context, Result};
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;
use vdbcook_bake::CookSettings;
use vdbcook_cook::{Figure, Format};
use vdbcook_validate::{compare_assets, Comparison, Worst};
use vdbcook_vpak::Asset;

/// The formats tried, smallest per voxel first (the search sorts by file bytes).
const CANDIDATES: [Format; 5] = [Format::Bc7, Format::Bc4, Format::Unorm8, Format::F16, Format::F32];

struct Candidate {
    format: Format,
    bytes: u64,
    cooked: Cooked,
    /// The validation, once tried.
    outcome: Option<Comparison>,
}

impl Candidate {
    fn worst(&self) -> Option<Worst> {
        self.outcome.as_ref().and_then(|o| o.worst)
    }
    fn result(&self) -> &'static str {
        match &self.outcome {
            None => "not tried",
            Some(o) if o.gate_failure.is_none() => "pass",
            Some(_) => "fail",
        }
    }
}

pub fn run(args: &CookArgs, files: Vec<PathBuf>, started: Instant, bars: &Bars, quiet: bool) -> Result<u8> {
    let s = &args.settings;
    // The GPU first: without one, no cooking time is spent for nothing.
    let v = ValidateArgs::of_cook(s, args.output.clone(), args.inputs.clone(), None, GpuArgs::default(), args.json);
    let renderer = v.gpu.renderer()?;
    let opts = v.compare_options();
    let cooked = cook_formats(CookJob { settings: s, files, inputs: &args.inputs, base: None, reference: true }, &CANDIDATES, bars)?;
    let mut cands: Vec<Candidate> = cooked.into_iter().zip(CANDIDATES).map(|(cooked, format)| Candidate { format, bytes: vdbcook_vpak::file_len(&cooked.sections), cooked, outcome: None }).collect();
    let reference = cands.first_mut().and_then(|c| c.cooked.reference.take()).ok_or_else(|| anyhow!("no reference"))?;
    // Stable: equal sizes keep the order of CANDIDATES.
    cands.sort_by_key(|c| c.bytes);

    let name = args.output.display().to_string();
    let mut chosen = None;
    for (i, c) in cands.iter_mut().enumerate() {
        let asset = Asset::from_bytes(&vdbcook_vpak::assemble(&c.cooked.sections)).with_context(|| format!("the {} candidate", c.format.name()))?;
        let o = compare_assets(&asset, &name, &reference, &opts, || Ok::<_, std::convert::Infallible>(&renderer), bars)?;
        let pass = o.gate_failure.is_none();
        c.outcome = Some(o);
        if pass {
            chosen = Some(i);
            break;
        }
    }
    let best = chosen.or_else(|| best_reached(&cands, s));
    let table = table(&cands, s);
    let doc = json!({
        "gate": s.gate(),
        "candidates": cands.iter().map(|c| {
            let w = c.worst();
            json!({"format": c.format.name(), "bytes": c.bytes, "result": c.result(), "rmse": w.map(|w| Figure(w.rmse)), "psnr": w.map(|w| Figure(w.psnr)), "flip": w.map(|w| w.flip)})
        }).collect::<Vec<_>>(),
        "chosen": chosen.map(|i| cands[i].format.name()),
        "best": best.map(|i| cands[i].format.name()),
    });

    let Some(i) = chosen else {
        if !quiet {
            let text = if args.json { json_text(&json!({"output": name, "auto": doc})) } else { table };
            crate::emit_final(&text)?;
        }
        let reached = best.map_or_else(String::new, |b| {
            let c = &cands[b];
            let w = c.worst().map_or_else(String::new, |w| format!(": worst image psnr {:.1} dB, rmse {:.3e}, flip {:.4}", w.psnr, w.rmse, w.flip));
            format!("; the best reached: {} ({} bytes){w}", c.format.name(), c.bytes)
        });
        return Ok(crate::validate::gate(&Some(format!("--auto: no format meets the gate ({}){reached}; nothing written", s.gate().text()))));
    };
    let c = &mut cands[i];
    let t0 = Instant::now();
    vdbcook_vpak::write_file(&args.output, &c.cooked.sections, args.force).with_context(|| name.clone())?;
    let report = &mut c.cooked.report;
    report.timings.push(("write".into(), t0.elapsed().as_secs_f64()));
    report.timings.push(("total".into(), started.elapsed().as_secs_f64()));
    let o = c.outcome.as_ref().ok_or_else(|| anyhow!("no validation"))?;
    if !quiet {
        let text = if args.json {
            let mut v = summary_json(args, c.cooked.grid.as_deref(), &c.cooked.report, Some(&o.doc));
            if let Some(m) = v.as_object_mut() {
                m.insert("auto".into(), doc);
            }
            json_text(&v)
        } else {
            let mut t = summary_text(args, c.cooked.grid.as_deref(), &c.cooked.report);
            t += &o.text;
            t + &table
        };
        crate::emit_final(&text)?;
    }
    Ok(exit::SUCCESS)
}

/// The tried candidate closest to the gate: the lowest worst-image RMSE (so
/// the highest PSNR), or the lowest worst FLIP when --max-flip is the only
/// gate; the smaller file on a tie.
fn best_reached(cands: &[Candidate], s: &CookSettings) -> Option<usize> {
    let by_flip = s.gate().flip_only();
    let key = |w: Worst| if by_flip { w.flip } else { w.rmse };
    cands.iter().enumerate().filter_map(|(i, c)| c.worst().map(|w| (i, key(w)))).min_by(|a, b| a.1.total_cmp(&b.1)).map(|(i, _)| i)
}


fn table(cands: &[Candidate], s: &CookSettings) -> String {
    let tried = cands.iter().filter(|c| c.outcome.is_some()).count();
    let mut t = format!("auto: gate {}; tried {tried} of {} formats, smallest file first (worst image of each)\n", s.gate().text(), cands.len());
    t += &format!("  {:<8}{:>12}{:>12}{:>12}{:>9}  result\n", "format", "bytes", "psnr (dB)", "rmse", "flip");
    for c in cands {
        let (p, r, f) = c.worst().map_or_else(|| ("-".into(), "-".into(), "-".into()), |w| (format!("{:.2}", w.psnr), format!("{:.3e}", w.rmse), format!("{:.4}", w.flip)));
        t += &format!("  {:<8}{:>12}{p:>12}{r:>12}{f:>9}  {}\n", c.format.name(), c.bytes, c.result());
    }
    t
}

/// `--auto`'s own checks of the command line.
pub fn check(args: &CookArgs) -> Result<()> {
    let s = &args.settings;
    if !s.gate().is_set() {
        return Err(Usage("--auto needs a quality gate: --min-psnr, --max-rmse or --max-flip".into()).into());
    }
    Ok(())
}

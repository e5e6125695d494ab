//! The `--auto` search: every format cooked from one read of the frames,
//! compared smallest file first; the first whose images meet the gate wins.

use crate::cook::{cook_formats, CookJob, Cooked};
use crate::{Error, Result};
use serde_json::json;
use vdbcook_cook::{Figure, Format, Progress};
use vdbcook_validate::{compare_assets, CompareOptions, Comparison, Gate, Renderer, Worst};

/// The formats tried, smallest per voxel first (the search sorts by file bytes).
pub const CANDIDATES: [Format; 5] = [Format::Bc7, Format::Bc4, Format::Unorm8, Format::F16, Format::F32];

/// One format of the search.
pub struct Candidate {
    pub format: Format,
    /// The asset's file size.
    pub bytes: u64,
    pub cooked: Cooked,
    /// The comparison, once tried.
    pub outcome: Option<Comparison>,
}

impl Candidate {
    pub fn worst(&self) -> Option<Worst> {
        self.outcome.as_ref().and_then(|o| o.worst)
    }
    /// "pass", "fail" or "not tried".
    pub fn result(&self) -> &'static str {
        match &self.outcome {
            None => "not tried",
            Some(o) if o.passed() => "pass",
            Some(_) => "fail",
        }
    }
}

/// What the search found: the candidates smallest file first, the one chosen
/// (the first to meet the gate) and the best reached.
pub struct Search {
    pub gate: Gate,
    pub candidates: Vec<Candidate>,
    pub chosen: Option<usize>,
    /// The chosen one, else the tried candidate closest to the gate.
    pub best: Option<usize>,
}

/// Cooks `job` in every format of [`CANDIDATES`] (and its reference) from one
/// read of its frames and compares them with `opts` (its gate must be set),
/// smallest file first, until one meets the gate. `name` names the asset in
/// the comparison.
pub fn search(job: CookJob, opts: &CompareOptions, name: &str, renderer: &Renderer, bars: &dyn Progress) -> Result<Search> {
    let cooked = cook_formats(CookJob { reference: true, ..job }, &CANDIDATES, bars)?;
    let mut cands: Vec<Candidate> = cooked.into_iter().zip(CANDIDATES).map(|(cooked, format)| Candidate { format, bytes: cooked.asset.bytes().len() as u64, cooked, outcome: None }).collect();
    let reference = cands.first_mut().and_then(|c| c.cooked.reference.take()).ok_or_else(|| Error::Failed("no reference".into()))?;
    // Stable: equal sizes keep the order of CANDIDATES.
    cands.sort_by_key(|c| c.bytes);
    let mut chosen = None;
    for (i, c) in cands.iter_mut().enumerate() {
        let o = compare_assets(&c.cooked.asset, name, &reference, opts, || Ok::<_, std::convert::Infallible>(renderer), bars)?;
        let pass = o.passed();
        c.outcome = Some(o);
        if pass {
            chosen = Some(i);
            break;
        }
    }
    let best = chosen.or_else(|| best_reached(&cands, &opts.gate));
    Ok(Search { gate: opts.gate, candidates: cands, chosen, best })
}

/// The tried candidate closest to the gate: the lowest worst-image RMSE (so
/// the highest PSNR), or the lowest worst FLIP when FLIP is the only budget;
/// the smaller file on a tie.
fn best_reached(cands: &[Candidate], gate: &Gate) -> Option<usize> {
    let by_flip = gate.flip_only();
    let key = |w: Worst| if by_flip { w.flip } else { w.rmse };
    cands.iter().enumerate().filter_map(|(i, c)| c.worst().map(|w| (i, key(w)))).min_by(|a, b| a.1.total_cmp(&b.1)).map(|(i, _)| i)
}

impl Search {
    /// The table of candidates (human text).
    pub fn table(&self) -> String {
        let cands = &self.candidates;
        let tried = cands.iter().filter(|c| c.outcome.is_some()).count();
        let mut t = format!("auto: gate {}; tried {tried} of {} formats, smallest file first (worst image of each)\n", self.gate.text(), cands.len());
        t += &format!("  {:<8}{:>12}{:>12}{:>12}{:>9}  result\n", "format", "bytes", "psnr (dB)", "rmse", "flip");
        for c in cands {
            let (p, r, f) = c.worst().map_or_else(|| ("-".into(), "-".into(), "-".into()), |w| (format!("{:.2}", w.psnr), format!("{:.3e}", w.rmse), format!("{:.4}", w.flip)));
            t += &format!("  {:<8}{:>12}{p:>12}{r:>12}{f:>9}  {}\n", c.format.name(), c.bytes, c.result());
        }
        t
    }

    /// The search as JSON (`auto` in cook's JSON).
    pub fn doc(&self) -> serde_json::Value {
        let cands = &self.candidates;
        json!({
            "gate": self.gate,
            "candidates": cands.iter().map(|c| {
                let w = c.worst();
                json!({"format": c.format.name(), "bytes": c.bytes, "result": c.result(), "rmse": w.map(|w| Figure(w.rmse)), "psnr": w.map(|w| Figure(w.psnr)), "flip": w.map(|w| w.flip)})
            }).collect::<Vec<_>>(),
            "chosen": self.chosen.map(|i| cands[i].format.name()),
            "best": self.best.map(|i| cands[i].format.name()),
        })
    }

    /// Why no candidate was chosen (none when one was).
    pub fn failure(&self) -> Option<String> {
        if self.chosen.is_some() {
            return None;
        }
        let reached = self.best.map_or_else(String::new, |b| {
            let c = &self.candidates[b];
            let w = c.worst().map_or_else(String::new, |w| format!(": worst image psnr {:.1} dB, rmse {:.3e}, flip {:.4}", w.psnr, w.rmse, w.flip));
            format!("; the best reached: {} ({} bytes){w}", c.format.name(), c.bytes)
        });
        Some(format!("--auto: no format meets the gate ({}){reached}; nothing written", self.gate.text()))
    }
}

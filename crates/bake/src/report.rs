//! The bake's one report: per asset what happened and what it cost, as JSON
//! (docs/bake-json.md), JUnit XML and a self-contained HTML page; and the
//! merge of shards' reports into one.

use crate::{Error, Shard};
use serde::{Deserialize, Serialize};
use std::fmt::Write;

/// Schema version of report.json.
pub const REPORT_VERSION: u32 = 1;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Status {
    /// Cooked by this run.
    Baked,
    /// Unchanged key: taken from the output in place or from the cache.
    Cached,
    /// The cook (or reading a source, or writing) failed.
    Failed,
    /// Cooked or cached, but a quality gate failed.
    GateFailed,
    /// Not attempted: an earlier asset failed and the bake was told to stop (`--fail-fast`).
    Skipped,
}

impl Status {
    pub fn name(self) -> &'static str {
        match self {
            Status::Baked => "baked",
            Status::Cached => "cached",
            Status::Failed => "failed",
            Status::GateFailed => "gate-failed",
            Status::Skipped => "skipped",
        }
    }
}

/// Image-domain figures of a validation (the worst image over every frame and view).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Validation {
    pub adapter: String,
    pub views: u32,
    pub size: [u32; 2],
    pub images: usize,
    pub worst_frame: usize,
    pub worst_view: usize,
    pub image_rmse: f64,
    /// `None` for identical images.
    pub image_psnr: Option<f64>,
    pub mean_image_rmse: f64,
    /// The largest mean FLIP error of an image (`None` in records written before FLIP).
    #[serde(default)]
    pub image_flip: Option<f64>,
}

/// What a cook and its validation found, recorded in the asset itself (a
/// `bake_record` setting of its metadata) so a cached asset reports it again.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Record {
    pub frames: Option<u32>,
    pub format: Option<String>,
    pub grid: Option<String>,
    pub active_voxels: Option<u64>,
    pub bits_per_active_voxel: Option<f64>,
    pub voxel_rmse: Option<f64>,
    pub voxel_psnr: Option<f64>,
    pub validation: Option<Validation>,
    /// The gate's verdict when it failed.
    pub gate_failure: Option<String>,
    /// A 256×256 PNG of the asset's middle frame, exposed from the volume, base64.
    pub thumbnail: Option<String>,
    /// Per channel, its formats and their bricks (`None` in records written before them).
    #[serde(default)]
    pub channels: Option<Vec<ChannelFormats>>,
    /// Bytes a renderer uploads (every section but the metadata, restored): the
    /// file's size unless it is supercompressed (`None` in records written before it).
    #[serde(default)]
    pub gpu_bytes: Option<u64>,
}

/// One channel's formats: the cook report's `formats`, in its order (cheapest first).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChannelFormats {
    pub name: String,
    pub formats: Vec<FormatBricks>,
}

/// A format of a channel and the distinct bricks stored in it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FormatBricks {
    pub format: String,
    pub bricks: u32,
}

impl From<&vdbcook_cook::ChannelReport> for ChannelFormats {
    fn from(c: &vdbcook_cook::ChannelReport) -> ChannelFormats {
        ChannelFormats { name: c.name.clone(), formats: c.formats.iter().map(|f| FormatBricks { format: f.format.name().to_string(), bricks: f.bricks }).collect() }
    }
}

impl ChannelFormats {
    /// "bc7 61 %, bc4 30 %, unorm8 9 %": each format's share of the channel's
    /// bricks (one format alone: just its name).
    pub fn shares(&self) -> String {
        if let [one] = &self.formats[..] {
            return one.format.clone();
        }
        let total: u64 = self.formats.iter().map(|f| u64::from(f.bricks)).sum();
        let pct = |b: u32| match (u64::from(b) * 100).checked_div(total) {
            _ if b == 0 => "0 %".to_string(),
            Some(0) | None => "<1 %".to_string(),
            Some(_) => format!("{:.0} %", f64::from(b) * 100.0 / total as f64),
        };
        self.formats.iter().map(|f| format!("{} {}", f.format, pct(f.bricks))).collect::<Vec<_>>().join(", ")
    }

    /// [`ChannelFormats::shares`] with each "format N %" unbreakable, for HTML.
    fn shares_html(&self) -> String {
        esc(&self.shares()).split(", ").map(|x| x.replace(' ', "&nbsp;")).collect::<Vec<_>>().join(", ")
    }
}

impl Record {
    pub fn to_setting(&self) -> String {
        serde_json::to_string(self).unwrap_or_default()
    }
    pub fn from_setting(s: &str) -> Option<Record> {
        serde_json::from_str(s).ok()
    }
}

/// The budgets an asset was held to.
pub use vdbcook_validate::Gate;

/// One asset of the report.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AssetReport {
    /// Position in the manifest, from 0.
    pub index: usize,
    pub name: String,
    pub status: Status,
    /// As written in the manifest (relative to the output directory).
    pub output: String,
    /// Size of the asset; `None` when it failed.
    pub bytes: Option<u64>,
    pub cache_key: String,
    /// As written in the manifest.
    pub inputs: Vec<String>,
    /// Input files after expansion.
    pub files: usize,
    #[serde(flatten)]
    pub record: Record,
    pub validate: bool,
    pub gate: Gate,
    /// Why it failed (cook error or gate verdict).
    pub message: Option<String>,
    /// Per-asset validation page, relative to the output directory, when one exists.
    pub validation_report: Option<String>,
    pub seconds: f64,
    /// A part of an asset with `parts` (in a shard's report; `bake --merge` joins them).
    #[serde(default)]
    pub part: Option<PartRef>,
}

/// Which part of its asset an entry is, and its part file.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct PartRef {
    /// From 1.
    pub index: u32,
    pub count: u32,
    /// The part file, relative to the output directory (and so to the report
    /// of a shard whose report directory is its output directory).
    pub file: String,
}

impl AssetReport {
    /// "smoke", or "smoke (part 1/2)" for a part's entry.
    pub fn label(&self) -> String {
        match &self.part {
            Some(p) => format!("{} (part {}/{})", self.name, p.index, p.count),
            None => self.name.clone(),
        }
    }

    /// Where the entry sorts: its asset's position, then its part's.
    pub fn order(&self) -> (usize, u32) {
        (self.index, self.part.as_ref().map_or(0, |p| p.index))
    }
}

#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Summary {
    pub assets: usize,
    pub baked: usize,
    pub cached: usize,
    pub failed: usize,
    pub gate_failed: usize,
    pub skipped: usize,
}

impl Summary {
    pub fn of(assets: &[AssetReport]) -> Summary {
        let count = |s: Status| assets.iter().filter(|a| a.status == s).count();
        Summary {
            assets: assets.len(),
            baked: count(Status::Baked),
            cached: count(Status::Cached),
            failed: count(Status::Failed),
            gate_failed: count(Status::GateFailed),
            skipped: count(Status::Skipped),
        }
    }
}

/// The whole report (report.json, `bake --json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Report {
    pub version: u32,
    pub tool: String,
    /// The manifest's path as given.
    pub manifest: String,
    /// The shard this report covers; `None` for a whole bake or a merge.
    pub shard: Option<Shard>,
    /// Shards merged into this report (0 when not merged).
    pub merged: usize,
    pub summary: Summary,
    pub seconds: f64,
    pub assets: Vec<AssetReport>,
}

impl Report {
    pub fn new(tool: String, manifest: String, shard: Option<Shard>, mut assets: Vec<AssetReport>, seconds: f64) -> Report {
        assets.sort_by_key(AssetReport::order);
        Report { version: REPORT_VERSION, tool, manifest, shard, merged: 0, summary: Summary::of(&assets), seconds, assets }
    }

    pub fn to_json(&self) -> String {
        format!("{}\n", serde_json::to_string_pretty(self).unwrap_or_default())
    }

    /// Reads a report; `name` is for errors.
    pub fn from_json(name: &str, text: &str) -> Result<Report, Error> {
        let r: Report = serde_json::from_str(text).map_err(|e| Error::Report(name.into(), format!("not a bake report: {e}")))?;
        if r.version != REPORT_VERSION {
            return Err(Error::Report(name.into(), format!("schema version {} (expected {REPORT_VERSION})", r.version)));
        }
        Ok(r)
    }

    /// Joins shards' reports: every asset once, in manifest order. Reports of
    /// different manifests, or two reports with the same asset, are refused.
    pub fn merge(parts: Vec<(String, Report)>) -> Result<Report, Error> {
        let Some((_, first)) = parts.first() else {
            return Err(Error::Report(String::new(), "nothing to merge".into()));
        };
        let (tool, manifest) = (first.tool.clone(), first.manifest.clone());
        let mut assets: Vec<AssetReport> = Vec::new();
        let mut seconds = 0.0f64;
        let n = parts.len();
        for (name, r) in parts {
            if r.manifest != manifest {
                return Err(Error::Report(name, format!("is a report of manifest \"{}\", not \"{manifest}\"", r.manifest)));
            }
            for a in r.assets {
                let part = |x: &AssetReport| x.part.as_ref().map(|p| p.index);
                if let Some(o) = assets.iter().find(|o| (o.index == a.index || o.name == a.name) && part(o) == part(&a)) {
                    let what = o.part.as_ref().map_or(String::new(), |p| format!(" (part {}/{})", p.index, p.count));
                    return Err(Error::Report(name, format!("asset \"{}\"{what} is in two reports (expected the reports of disjoint shards)", o.name)));
                }
                assets.push(a);
            }
            seconds = seconds.max(r.seconds);
        }
        let mut merged = Report::new(tool, manifest, None, assets, seconds);
        merged.merged = n;
        Ok(merged)
    }

    /// JUnit XML: one test suite, one test case per asset; a failed cook or
    /// gate is a `<failure>` with its message.
    pub fn to_junit(&self) -> String {
        let failures = self.summary.failed + self.summary.gate_failed;
        let skipped = self.summary.skipped;
        let mut s = String::from("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
        let _ = writeln!(s, "<testsuites name=\"vdbcook bake\" tests=\"{}\" failures=\"{failures}\" errors=\"0\" time=\"{:.3}\">", self.assets.len(), self.seconds);
        let _ = writeln!(s, "  <testsuite name=\"{}\" tests=\"{}\" failures=\"{failures}\" errors=\"0\" skipped=\"{skipped}\" time=\"{:.3}\">", xml(&self.manifest), self.assets.len(), self.seconds);
        for a in &self.assets {
            let _ = write!(s, "    <testcase name=\"{}\" classname=\"vdbcook.bake\" time=\"{:.3}\"", xml(&a.label()), a.seconds);
            let msg = a.message.clone().unwrap_or_default();
            match a.status {
                Status::Failed => {
                    let _ = writeln!(s, ">\n      <failure message=\"{}\" type=\"cook\">{}</failure>\n    </testcase>", xml(&msg), xml(&msg));
                }
                Status::GateFailed => {
                    let _ = writeln!(s, ">\n      <failure message=\"{}\" type=\"quality-gate\">{}</failure>\n    </testcase>", xml(&msg), xml(&msg));
                }
                Status::Skipped => {
                    let _ = writeln!(s, ">\n      <skipped message=\"{}\"/>\n    </testcase>", xml(&msg));
                }
                Status::Baked | Status::Cached => {
                    let _ = writeln!(s, ">\n      <system-out>{} {} ({} bytes, key {})</system-out>\n    </testcase>", a.status.name(), xml(&a.output), a.bytes.unwrap_or(0), a.cache_key);
                }
            }
        }
        s += "  </testsuite>\n</testsuites>\n";
        s
    }

    /// A self-contained HTML page: one sortable table row per asset, with its
    /// thumbnail; it fits a 1280 px wide window (long text wraps, the formats
    /// are listed per channel).
    pub fn to_html(&self) -> String {
        let mut rows = String::new();
        for a in &self.assets {
            let r = &a.record;
            let v = r.validation.as_ref();
            let thumb = match &r.thumbnail {
                Some(b64) => format!("<img alt='{}' src='data:image/png;base64,{}'>", esc(&a.name), b64),
                None => "<span class='none'>no preview</span>".into(),
            };
            let link = match &a.validation_report {
                Some(p) => format!("<div class='sub'><a href='{}'>validation report</a></div>", esc(p)),
                None => String::new(),
            };
            let cell = |sort: Option<f64>, text: String| match sort {
                Some(x) if x.is_finite() => format!("<td data-v='{x}'>{text}</td>"),
                _ => format!("<td data-v=''>{text}</td>"),
            };
            let gate = match gate_text(a) {
                "" => String::new(),
                g => format!("<div class='sub'>gate {g}</div>"),
            };
            let _ = writeln!(
                rows,
                "<tr class='{st}'><td class='pic'>{thumb}</td><td class='t' data-v='{n}'>{n}<div class='sub'>{out}</div>{link}</td><td class='t' data-v='{st}'>{st}{gate}{msg}</td>{frames}{fmt}{bytes}{bpv}{vr}{vp}{ir}{ip}{fl}{secs}</tr>",
                st = a.status.name(),
                n = esc(&a.label()),
                out = esc(&a.output),
                msg = a.message.as_ref().map(|m| format!("<div class='sub msg'>{}</div>", esc(m))).unwrap_or_default(),
                frames = cell(r.frames.map(f64::from), r.frames.map(|f| f.to_string()).unwrap_or_default()),
                fmt = format_cell(r),
                bytes = cell(
                    a.bytes.map(|b| b as f64),
                    match (a.bytes, r.gpu_bytes) {
                        // Supercompressed: the GPU's bytes beside the file's.
                        (Some(b), Some(g)) if g > b => format!("{}<div class='sub'>{} on the GPU</div>", human_bytes(b), human_bytes(g)),
                        (b, _) => b.map(human_bytes).unwrap_or_default(),
                    }
                ),
                bpv = cell(r.bits_per_active_voxel, r.bits_per_active_voxel.map(|b| format!("{b:.3}")).unwrap_or_default()),
                vr = cell(r.voxel_rmse, r.voxel_rmse.map(sci).unwrap_or_default()),
                vp = cell(r.voxel_psnr, psnr_text(r.voxel_rmse, r.voxel_psnr)),
                ir = cell(v.map(|v| v.image_rmse), v.map(|v| sci(v.image_rmse)).unwrap_or_default()),
                ip = cell(v.and_then(|v| v.image_psnr), v.map(|v| psnr_text(Some(v.image_rmse), v.image_psnr)).unwrap_or_default()),
                fl = cell(v.and_then(|v| v.image_flip), v.and_then(|v| v.image_flip).map(|f| format!("{f:.4}")).unwrap_or_default()),
                secs = cell(Some(a.seconds), format!("{:.2} s", a.seconds)),
            );
        }
        let s = &self.summary;
        let scope = match (self.shard, self.merged) {
            (Some(sh), _) => format!(", shard {sh}"),
            (None, n) if n > 0 => format!(", merged from {n} reports"),
            _ => String::new(),
        };
        format!(
            "<!doctype html>\n<html lang='en'><head><meta charset='utf-8'><title>vdbcook bake: {m}</title>\n<meta name='viewport' content='width=device-width'>\n<style>\
body{{font-family:sans-serif;margin:1em;color:#222;font-size:14px}}h1{{font-size:150%;margin:0 0 .3em}}p{{max-width:60em;overflow-wrap:anywhere}}\
table{{border-collapse:collapse;max-width:100%}}th,td{{border:1px solid #ccc;padding:3px 6px;text-align:right;vertical-align:top}}td{{white-space:nowrap}}\
th{{background:#f3f3f3;cursor:pointer;user-select:none;font-weight:600;vertical-align:bottom}}th:nth-child(-n+3),th:nth-child(5){{text-align:left}}th.asc::after{{content:' \\25b2'}}th.desc::after{{content:' \\25bc'}}\
td.t{{text-align:left;white-space:normal;overflow-wrap:anywhere;min-width:6em;max-width:14em}}td.pic{{padding:2px;text-align:center}}\
img{{width:256px;height:256px;background:#000;display:block}}.sub{{color:#777;font-size:85%}}.none{{color:#999}}\
.ch{{margin-bottom:2px}}.ch b{{font-weight:600}}details summary{{cursor:pointer}}td.fmt{{min-width:9em;max-width:15em}}\
tr.failed td:nth-child(3),tr.skipped td:nth-child(3),tr.gate-failed td:nth-child(3){{color:#b00;font-weight:bold}}td .sub{{font-weight:normal}}</style></head><body>\n\
<h1>vdbcook bake</h1>\n<p>{m}{scope}: {n} assets, {b} baked, {c} cached, {f} failed, {g} failed a quality gate, {k} skipped; {t:.1}&nbsp;s; {tool}.</p>\n\
<p class='sub'>Click a column heading to sort. Formats: each channel's formats and their share of its bricks. Image RMSE / PSNR / FLIP: the worst of every frame and view against a lossless reference render (FLIP: NVIDIA's perceptual error, 0 to 1, at 67 pixels per degree); voxel RMSE / PSNR over every active voxel. Previews are exposed to their volume's brightness; the validation pages use the fixed scene.</p>\n\
<table id='assets'><thead><tr><th>preview</th><th>asset</th><th>status</th><th>frames</th><th>format</th><th>bytes</th><th>bits per active voxel</th>\
<th>voxel RMSE</th><th>voxel PSNR (dB)</th><th>image RMSE</th><th>image PSNR (dB)</th><th>image FLIP</th><th>time</th></tr></thead>\n<tbody>\n{rows}</tbody></table>\n\
<script>\n(function () {{\n  var table = document.getElementById('assets');\n  var heads = table.tHead.rows[0].cells;\n  for (var i = 0; i < heads.length; i++) {{\n    heads[i].addEventListener('click', sorter(i));\n  }}\n\
  function sorter(col) {{\n    return function () {{\n      var th = heads[col], asc = !th.classList.contains('asc');\n      for (var k = 0; k < heads.length; k++) {{ heads[k].classList.remove('asc', 'desc'); }}\n      th.classList.add(asc ? 'asc' : 'desc');\n\
      var body = table.tBodies[0], rows = Array.prototype.slice.call(body.rows);\n      rows.sort(function (a, b) {{\n        var x = key(a, col), y = key(b, col);\n        if (x.n !== y.n) {{ return x.n ? -1 : 1; }}\n        var c = x.n ? x.v - y.v : String(x.v).localeCompare(String(y.v));\n        return asc ? c : -c;\n      }});\n\
      rows.forEach(function (r) {{ body.appendChild(r); }});\n    }};\n  }}\n  function key(row, col) {{\n    var cell = row.cells[col], v = cell.getAttribute('data-v');\n    if (v === null) {{ v = cell.textContent; }}\n    var n = v !== '' && !isNaN(Number(v));\n    return {{ n: n, v: n ? Number(v) : v }};\n  }}\n}})();\n</script>\n</body></html>\n",
            m = esc(&self.manifest),
            n = s.assets,
            b = s.baked,
            c = s.cached,
            f = s.failed,
            g = s.gate_failed,
            k = s.skipped,
            t = self.seconds,
            tool = esc(&self.tool),
        )
    }
}

/// The format cell: a line per channel ("density bc7 61 %, bc4 30 %"), behind
/// a toggle past three channels; records without channels show the joined
/// formats, breakable at each '+'.
fn format_cell(r: &Record) -> String {
    let all = esc(r.format.as_deref().unwrap_or(""));
    let body = match r.channels.as_deref() {
        Some(chs) if !chs.is_empty() => {
            let lines: String = chs.iter().map(|c| format!("<div class='ch'><b>{}</b> {}</div>", esc(&c.name), c.shares_html())).collect();
            if chs.len() > 3 {
                format!("<details><summary>{} channels</summary>{lines}</details>", chs.len())
            } else {
                lines
            }
        }
        _ => all.replace('+', "+<wbr>"),
    };
    format!("<td class='t fmt' data-v='{all}'>{body}</td>")
}

fn gate_text(a: &AssetReport) -> &'static str {
    match (a.status, a.gate.is_set()) {
        (Status::GateFailed, _) => "failed",
        (Status::Failed | Status::Skipped, _) => "",
        (_, true) => "held",
        (_, false) => "none",
    }
}

fn psnr_text(rmse: Option<f64>, psnr: Option<f64>) -> String {
    match (rmse, psnr) {
        (_, Some(p)) => format!("{p:.1}"),
        (Some(0.0), None) => "∞ (exact)".into(),
        _ => String::new(),
    }
}

fn sci(x: f64) -> String {
    if x == 0.0 {
        "0".into()
    } else {
        format!("{x:.2e}")
    }
}

/// 1234567 -> "1.23 MB".
pub fn human_bytes(b: u64) -> String {
    match b {
        0..1_000 => format!("{b} B"),
        1_000..1_000_000 => format!("{:.1} kB", b as f64 / 1e3),
        1_000_000..1_000_000_000 => format!("{:.2} MB", b as f64 / 1e6),
        _ => format!("{:.2} GB", b as f64 / 1e9),
    }
}

/// Escapes text for HTML.
pub fn esc(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;").replace('\'', "&#39;")
}

/// Escapes text for XML attributes and content; drops characters XML 1.0 cannot hold.
pub fn xml(s: &str) -> String {
    s.chars()
        .filter(|&c| matches!(c, '\t' | '\n' | '\r') || (c >= ' ' && c != '\u{fffe}' && c != '\u{ffff}'))
        .collect::<String>()
        .replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
        .replace('\'', "&apos;")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn asset(index: usize, status: Status) -> AssetReport {
        AssetReport {
            index,
            name: format!("a{index}"),
            status,
            output: format!("a{index}.vpak"),
            bytes: Some(1000 + index as u64),
            cache_key: format!("{index:032x}"),
            inputs: vec!["x.vdb".into()],
            files: 1,
            record: Record { frames: Some(2), format: Some("bc7".into()), voxel_rmse: Some(0.01), ..Record::default() },
            validate: false,
            gate: Gate::default(),
            message: (status == Status::Failed).then(|| "x.vdb: bad <magic> & \"stuff\"".into()),
            validation_report: None,
            seconds: 0.5,
            part: None,
        }
    }

    #[test]
    fn merge_is_the_whole_in_manifest_order() {
        let all: Vec<AssetReport> = (0..5).map(|i| asset(i, if i == 3 { Status::Failed } else { Status::Baked })).collect();
        let whole = Report::new("t".into(), "bake.toml".into(), None, all.clone(), 1.0);
        let parts: Vec<(String, Report)> = (1..=2u32)
            .map(|k| {
                let sh = Shard { index: k, count: 2 };
                let mine = all.iter().filter(|a| sh.takes(a.index)).cloned().collect();
                (format!("r{k}"), Report::new("t".into(), "bake.toml".into(), Some(sh), mine, 0.6))
            })
            .collect();
        let merged = Report::merge(parts.clone()).unwrap();
        assert_eq!(merged.assets, whole.assets);
        assert_eq!(merged.summary, whole.summary);
        let back = Report::from_json("r", &merged.to_json()).unwrap();
        assert_eq!(back, merged);
        let twice = vec![parts[0].clone(), parts[0].clone()];
        assert!(Report::merge(twice).is_err());
    }

    #[test]
    fn formats_are_shown_per_channel() {
        let ch = |name: &str, f: &[(&str, u32)]| ChannelFormats { name: name.into(), formats: f.iter().map(|(f, b)| FormatBricks { format: (*f).into(), bricks: *b }).collect() };
        let density = ch("density", &[("constant", 1), ("bc7", 61), ("bc4", 30), ("unorm8", 8), ("f16", 0)]);
        assert_eq!(density.shares(), "constant 1 %, bc7 61 %, bc4 30 %, unorm8 8 %, f16 0 %");
        assert_eq!(ch("t", &[("bc7", 1), ("unorm8", 999)]).shares(), "bc7 <1 %, unorm8 100 %");
        assert_eq!(ch("t", &[("bc4", 7)]).shares(), "bc4");
        let mut r = Record { format: Some("constant+bc7+bc4+unorm8+f16".into()), channels: Some(vec![density.clone()]), ..Record::default() };
        let cell = format_cell(&r);
        assert!(cell.contains("<b>density</b> constant&nbsp;1&nbsp;%, bc7&nbsp;61&nbsp;%,") && !cell.contains("<details>"), "{cell}");
        r.channels = Some((0..4).map(|k| ch(&format!("c{k}"), &[("bc7", 1)])).collect());
        assert!(format_cell(&r).contains("<details><summary>4 channels</summary>"));
        // A record written before channels were recorded reads back, and shows the joined formats.
        let mut old: serde_json::Value = serde_json::from_str(&r.to_setting()).unwrap();
        old.as_object_mut().unwrap().remove("channels");
        let back = Record::from_setting(&old.to_string()).unwrap();
        assert_eq!(back.channels, None);
        assert!(format_cell(&back).contains("constant+<wbr>bc7+<wbr>bc4"));
    }

    #[test]
    fn junit_and_html_escape_messages() {
        let r = Report::new("t".into(), "b&.toml".into(), None, vec![asset(0, Status::Failed), asset(1, Status::Cached)], 1.0);
        let x = r.to_junit();
        assert!(x.contains("failures=\"1\"") && x.contains("&lt;magic&gt; &amp; &quot;stuff&quot;") && x.contains("b&amp;.toml"), "{x}");
        let h = r.to_html();
        assert!(h.contains("&lt;magic&gt;") && !h.contains("<magic>"));
        assert_eq!(xml("a\u{1}b"), "ab");
        assert_eq!(human_bytes(1_234_567), "1.23 MB");
    }
}

//! One bake asset's step: left in place when its output carries its key,
//! copied from the cache, or cooked (through vdbcook-pipeline), validated
//! (through vdbcook-validate), given a preview and its record, written, and
//! stored in the cache. Workers share one [`Baker`].

use crate::manifest::resolve;
use crate::parts::{self, PartNo, PartNote};
use crate::{place, AssetReport, ChannelFormats, PartRef, PlannedAsset, Record, Status, Validation};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::Instant;
use vdbcook_pipeline::cook::Part;
use vdbcook_pipeline::{cook_asset, one_line, Context, CookJob, Cooked, Error, Result};
use vdbcook_validate::report::{base64, thumbnail};
use vdbcook_validate::{compare_assets, Comparison, Renderer};
use vdbcook_vpak::Asset;

type BoxError = Box<dyn std::error::Error + Send + Sync>;

/// What every worker shares.
pub struct Baker<'g> {
    out_dir: PathBuf,
    report_dir: PathBuf,
    cache: Option<PathBuf>,
    base: PathBuf,
    /// Replace anything at an output or cache path (`--force`).
    force: bool,
    /// Opens the GPU device (the caller's choice of adapter), once, when first needed.
    open: Box<dyn Fn() -> Result<Renderer, BoxError> + Send + Sync + 'g>,
    /// The one renderer every worker shares (one device, its pipelines compiled
    /// once), or why none could be opened.
    renderer: OnceLock<std::result::Result<Renderer, String>>,
}

impl<'g> Baker<'g> {
    /// Outputs go below `out_dir`, validation pages below `report_dir`; `base`
    /// is the manifest's directory (sources are recorded relative to it);
    /// `open` opens the GPU device when one is first needed.
    pub fn new(out_dir: PathBuf, report_dir: PathBuf, cache: Option<PathBuf>, base: PathBuf, force: bool, open: impl Fn() -> Result<Renderer, BoxError> + Send + Sync + 'g) -> Baker<'g> {
        Baker { out_dir, report_dir, cache, base, force, open: Box::new(open), renderer: OnceLock::new() }
    }

    fn renderer(&self) -> Result<&Renderer> {
        self.renderer.get_or_init(|| (self.open)().map_err(|e| one_line(&Error::Other(e)))).as_ref().map_err(|e| Error::Failed(e.clone()))
    }
}

/// The record and size of a valid asset at `path` that carries `key`.
pub fn cached(path: &Path, key: &str) -> Option<(Record, u64)> {
    // Opening checks every checksum and the padding, the validator the rest
    // every reader relies on: a corrupted or inconsistent asset is not a hit.
    let asset = Asset::open(path).ok()?;
    let meta = asset.check().ok()?;
    let get = |k: &str| meta.settings.iter().find(|(n, _)| n == k).map(|(_, v)| v.as_str());
    if get("cache_key")? != key {
        return None;
    }
    Some((Record::from_setting(get("bake_record")?)?, asset.bytes().len() as u64))
}

pub fn skipped(a: &PlannedAsset) -> AssetReport {
    let mut r = blank(a);
    r.status = Status::Skipped;
    r.message = Some("not baked: an earlier asset failed (--fail-fast)".into());
    r
}

fn blank(a: &PlannedAsset) -> AssetReport {
    AssetReport {
        index: a.index,
        name: a.name.clone(),
        status: Status::Failed,
        output: a.output.clone(),
        bytes: None,
        cache_key: a.key.clone(),
        inputs: a.inputs.clone(),
        files: a.files.len() + a.with_files.len(),
        record: Record::default(),
        validate: a.settings.validate,
        gate: a.settings.gate,
        message: None,
        validation_report: None,
        seconds: 0.0,
        part: None,
    }
}

/// [`skipped`] for a unit: the asset, or one of its parts.
pub fn skipped_unit(a: &PlannedAsset, part: Option<PartNo>) -> AssetReport {
    let mut r = skipped(a);
    if let Some(p) = part {
        r.cache_key = parts::part_key(&a.key, p);
        r.part = Some(PartRef { index: p.index, count: p.count, file: parts::part_output(&a.output, p) });
    }
    r
}

/// Whether the asset is in place or in the cache with its key (so that a bake
/// with every part of it need cook none).
pub fn whole_cached(a: &PlannedAsset, ctx: &Baker) -> bool {
    cached(&resolve(&ctx.out_dir, &a.output), &a.key).is_some() || ctx.cache.as_ref().is_some_and(|c| cached(&c.join(format!("{}.vpak", a.key)), &a.key).is_some())
}

/// Bakes one unit: the asset ([`bake_one`]) or one of its parts, a part file
/// beside its output (`parts::part_output`), cached under its own key.
pub fn bake_unit(a: &PlannedAsset, part: Option<PartNo>, ctx: &Baker) -> AssetReport {
    let Some(p) = part else { return bake_one(a, ctx) };
    let t0 = Instant::now();
    let mut r = skipped_unit(a, Some(p));
    r.status = Status::Failed;
    r.message = None;
    let file = parts::part_output(&a.output, p);
    match obtain_part(a, p, &r.cache_key, ctx, &resolve(&ctx.out_dir, &file)) {
        Ok((status, note, bytes)) => {
            r.status = status;
            r.record = note.record;
            r.bytes = Some(bytes);
        }
        Err(e) => r.message = Some(one_line(&e)),
    }
    r.seconds = t0.elapsed().as_secs_f64();
    r
}

/// The part file at `out`: left in place, copied from the cache, or cooked.
fn obtain_part(a: &PlannedAsset, p: PartNo, key: &str, ctx: &Baker, out: &Path) -> Result<(Status, PartNote, u64)> {
    let cache_file = ctx.cache.as_ref().map(|c| c.join(format!("{key}.vpakpart")));
    obtain_with(
        out,
        cache_file,
        ctx,
        |path| parts::cached_part(path, key),
        || {
            let name = out.display().to_string();
            let part = Some(Part { index: p.index - 1, count: p.count });
            // Cooked into an unnamed file beside `out` that is never given a name: the part is written again with the bake's note.
            let job = CookJob { settings: &a.settings, files: a.files.clone(), inputs: &a.inputs, base: Some(ctx.base.clone()), reference: false, output: Some((out, true)), part };
            let mut cooked = cook_asset(job, &vdbcook_cook::NoProgress)?;
            let note = PartNote { asset_key: a.key.clone(), record: cook_record(&cooked), segments: cooked.report.segments.iter().map(|s| s.sums.clone()).collect() };
            let file = cooked.file.as_mut().ok_or_else(|| Error::Failed("a part is cooked into a file".into()))?;
            let (info, asset) = vdbcook_vpak::Asset::from_part_file(file.file()).with_context(|| name.clone())?;
            let extra = [("cache_key".to_string(), key.to_string()), (parts::PART_SETTING.to_string(), serde_json::to_string(&note).unwrap_or_default())];
            let bytes = parts::rewrite_part(&info, &asset, |m| m.settings.extend(extra.iter().cloned())).with_context(|| name.clone())?;
            Ok((bytes, note))
        },
    )
}

/// What a bake unit (an asset or a part) gives at `out`: the file left in
/// place when `hit` finds it current, else copied from `cache_file`, else
/// cooked (`cook`: its bytes and figures) and written to both.
fn obtain_with<T>(out: &Path, cache_file: Option<PathBuf>, ctx: &Baker, hit: impl Fn(&Path) -> Option<(T, u64)>, cook: impl FnOnce() -> Result<(Vec<u8>, T)>) -> Result<(Status, T, u64)> {
    if let Some((found, bytes)) = hit(out) {
        return Ok((Status::Cached, found, bytes));
    }
    let name = out.display().to_string();
    // Checked before the cook (so a refusal costs nothing) and again before
    // each write (the file may have appeared meanwhile).
    let may_write = |p: &Path| place::may_replace(p, ctx.force).map_err(Error::Failed);
    may_write(out)?;
    if let Some(parent) = out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).with_context(|| parent.display().to_string())?;
    }
    if let Some(cf) = &cache_file {
        if let Some((found, bytes)) = hit(cf) {
            let data = std::fs::read(cf).with_context(|| cf.display().to_string())?;
            may_write(out)?;
            vdbcook_vpak::write_atomic(out, &data, true).with_context(|| name.clone())?;
            return Ok((Status::Cached, found, bytes));
        }
        may_write(cf)?;
    }
    let (bytes, found) = cook()?;
    may_write(out)?;
    vdbcook_vpak::write_atomic(out, &bytes, true).with_context(|| name.clone())?;
    if let (Some(cf), Some(dir)) = (&cache_file, &ctx.cache) {
        std::fs::create_dir_all(dir).with_context(|| dir.display().to_string())?;
        may_write(cf)?;
        vdbcook_vpak::write_atomic(cf, &bytes, true).with_context(|| cf.display().to_string())?;
    }
    Ok((Status::Baked, found, bytes.len() as u64))
}

/// Joins the asset from its parts' files, which `units` (the reports of its
/// parts, every one of them) say were baked into the output directory; the
/// asset's report. A part that failed or was skipped fails (or skips) the
/// asset. The part files go once the asset is written (they are in the cache
/// when there is one).
pub fn join_parts(a: &PlannedAsset, units: &[&AssetReport], ctx: &Baker) -> AssetReport {
    let t0 = Instant::now();
    let mut r = blank(a);
    r.validate = false;
    if let Some(bad) = units.iter().find(|u| matches!(u.status, Status::Failed | Status::Skipped)) {
        let p = bad.part.as_ref().map_or(String::new(), |p| format!("{}/{}", p.index, p.count));
        r.status = bad.status;
        r.message = Some(format!("part {p}: {}", bad.message.as_deref().unwrap_or("failed")));
        return r;
    }
    let files: Vec<PathBuf> = units.iter().filter_map(|u| u.part.as_ref()).map(|p| resolve(&ctx.out_dir, &p.file)).collect();
    let out = resolve(&ctx.out_dir, &a.output);
    let thumb = |asset: &vdbcook_vpak::Asset| ctx.renderer().ok().and_then(|rd| preview(rd, asset));
    let joined = parts::join(&a.name, &files, &out, ctx.force, &thumb).and_then(|j| {
        if j.key != a.key {
            return Err(Error::Failed(format!("asset {}: its parts carry key {}, the manifest's is {}", a.name, j.key, a.key)));
        }
        if let Some(dir) = &ctx.cache {
            let cf = dir.join(format!("{}.vpak", a.key));
            place::may_replace(&cf, ctx.force).map_err(Error::Failed)?;
            std::fs::create_dir_all(dir).with_context(|| dir.display().to_string())?;
            std::fs::copy(&out, &cf).with_context(|| cf.display().to_string())?;
        }
        Ok(j)
    });
    match joined {
        Ok(j) => {
            r.status = if units.iter().any(|u| u.status == Status::Baked) { Status::Baked } else { Status::Cached };
            r.record = j.record;
            r.bytes = Some(j.bytes);
            for f in &files {
                let _ = std::fs::remove_file(f);
            }
        }
        Err(e) => r.message = Some(one_line(&e)),
    }
    r.seconds = t0.elapsed().as_secs_f64() + units.iter().map(|u| u.seconds).sum::<f64>();
    r
}

/// Bakes one asset (or finds it cached); never fails: a failure is its status.
pub fn bake_one(a: &PlannedAsset, ctx: &Baker) -> AssetReport {
    let t0 = Instant::now();
    let mut r = blank(a);
    let out = resolve(&ctx.out_dir, &a.output);
    match obtain(a, ctx, &out) {
        Ok((status, record, bytes)) => {
            r.status = if record.gate_failure.is_some() { Status::GateFailed } else { status };
            r.message = record.gate_failure.clone();
            r.record = record;
            r.bytes = Some(bytes);
        }
        Err(e) => r.message = Some(one_line(&e)),
    }
    let page = Path::new("validation").join(&a.name).join("report.html");
    if a.settings.validate && ctx.report_dir.join(&page).is_file() {
        r.validation_report = Some(page.to_string_lossy().replace('\\', "/"));
    }
    r.seconds = t0.elapsed().as_secs_f64();
    r
}

/// The asset at `out`: left in place, copied from the cache, or cooked.
fn obtain(a: &PlannedAsset, ctx: &Baker, out: &Path) -> Result<(Status, Record, u64)> {
    let cache_file = ctx.cache.as_ref().map(|c| c.join(format!("{}.vpak", a.key)));
    obtain_with(out, cache_file, ctx, |path| cached(path, &a.key), || cook_fresh(a, ctx))
}

/// Pixels on a side of a report preview (shown at that size in report.html).
const THUMBNAIL_SIZE: u32 = 256;

/// An asset's preview for the report (a PNG, base64), as a bake records it.
pub fn preview(renderer: &Renderer, asset: &vdbcook_vpak::Asset) -> Option<String> {
    thumbnail(renderer, asset, THUMBNAIL_SIZE).ok().map(|png| base64(&png))
}

fn finite(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

/// Cooks, validates and renders a thumbnail; returns the asset's bytes, with
/// the key and the record in its metadata.
fn cook_fresh(a: &PlannedAsset, ctx: &Baker) -> Result<(Vec<u8>, Record)> {
    let s = &a.settings;
    let cooked =
        cook_asset(CookJob { settings: s, files: a.files.clone(), inputs: &a.inputs, base: Some(ctx.base.clone()), reference: s.validate, output: None, part: None }, &vdbcook_cook::NoProgress)?;
    let mut record = cook_record(&cooked);
    let asset = &cooked.asset;
    if let Some(reference) = &cooked.reference {
        let o = compare_assets(asset, &a.output, reference, &s.compare_options(Some(ctx.report_dir.join("validation").join(&a.name))), || ctx.renderer(), &vdbcook_cook::NoProgress)
            .context("validating")?;
        record.validation = validation_figures(&o);
        record.gate_failure = o.gate_failure;
    }
    // A preview for the report; without a GPU (and no validation asked for) there is none.
    if let Ok(renderer) = ctx.renderer() {
        record.thumbnail = preview(renderer, asset);
    }
    // Every segment records the key and the record (segments share their settings).
    let extra = [("cache_key".to_string(), a.key.clone()), ("bake_record".to_string(), record.to_setting())];
    let bytes = vdbcook_vpak::segments::rewrite_metadata(asset, |m| m.settings.extend(extra.iter().cloned()))?;
    Ok((bytes, record))
}

/// What a cook found, as a bake records it.
fn cook_record(cooked: &Cooked) -> Record {
    let r = &cooked.report;
    Record {
        frames: Some(r.frames as u32),
        format: Some(r.format.clone()),
        grid: cooked.grid.clone(),
        active_voxels: Some(r.active_voxels),
        bits_per_active_voxel: Some(r.bits_per_active_voxel),
        voxel_rmse: Some(r.voxel_rmse),
        voxel_psnr: finite(r.voxel_psnr),
        channels: Some(r.channels.iter().map(ChannelFormats::from).collect()),
        gpu_bytes: Some(r.gpu_bytes),
        ..Record::default()
    }
}

/// The image figures of a validation: its first level's (the level its document reports).
fn validation_figures(o: &Comparison) -> Option<Validation> {
    let level = o.levels.first()?;
    let images = &level.shots;
    let mean = if images.is_empty() { 0.0 } else { images.iter().map(|i| i.metrics.rmse).sum::<f64>() / images.len() as f64 };
    let worst = level.worst_shot;
    Some(Validation {
        adapter: o.adapter.clone(),
        views: o.views,
        size: [o.size.width(), o.size.height()],
        images: images.len(),
        worst_frame: worst.map_or(0, |s| s.frame),
        worst_view: worst.map_or(0, |s| s.view),
        image_rmse: worst.map_or(0.0, |s| s.metrics.rmse),
        image_psnr: worst.and_then(|s| finite(s.metrics.psnr)),
        mean_image_rmse: mean,
        image_flip: level.shots.iter().map(|s| s.flip).reduce(f64::max),
    })
}

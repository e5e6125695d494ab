//! What source files' metadata says of time: EmberGen writes each frame's
//! `simulation_time`; some tools a frame rate. Gathered while frames are
//! read and reported with the cook; the asset's rate is `--fps`.

use vdbcook_cook::SourceTime;
use vdbcook_vdb::{MetaMap, VdbFile};

/// Keys of a frame's time in seconds, in the order looked for.
const TIME_KEYS: [&str; 2] = ["simulation_time", "time"];
/// Keys of a frame rate.
const RATE_KEYS: [&str; 3] = ["fps", "frame_rate", "framerate"];

/// One file's statement: (time key, seconds) and a frame rate.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Stated {
    pub time: Option<(&'static str, f64)>,
    pub fps: Option<f64>,
}

fn find(maps: &[&MetaMap], keys: &[&'static str]) -> Option<(&'static str, f64)> {
    keys.iter().find_map(|&k| maps.iter().find_map(|m| m.get(k).and_then(|v| v.as_f64()).filter(|v| v.is_finite()).map(|v| (k, v))))
}

/// What `vdb` states: its file-level metadata first, then its first grid's.
pub fn stated(vdb: &VdbFile) -> Stated {
    let mut maps = vec![&vdb.metadata];
    maps.extend(vdb.grids.first().map(|g| &g.metadata));
    Stated { time: find(&maps, &TIME_KEYS), fps: find(&maps, &RATE_KEYS).map(|(_, v)| v).filter(|&v| v > 0.0) }
}

/// The statements of a sequence's frames, in order, summed up (`None` when no file said anything).
pub fn summarize(frames: &[Stated]) -> Option<SourceTime> {
    let key = frames.iter().find_map(|s| s.time.map(|t| t.0));
    let times: Vec<f64> = frames.iter().filter_map(|s| s.time.filter(|t| Some(t.0) == key).map(|t| t.1)).collect();
    let stated_fps = frames.iter().find_map(|s| s.fps);
    if times.is_empty() && stated_fps.is_none() {
        return None;
    }
    let (first, last) = (times.first().copied().unwrap_or(0.0), times.last().copied().unwrap_or(0.0));
    let implied_fps = (times.len() > 1 && last > first).then(|| (times.len() - 1) as f64 / (last - first));
    Some(SourceTime { key: key.unwrap_or("").to_string(), frames: times.len(), first, last, implied_fps, stated_fps })
}

/// A number to `decimals` places, without trailing zeros (a float's 0.05000000074 as 0.05).
fn short(v: f64, decimals: usize) -> String {
    let t = format!("{v:.decimals$}");
    t.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// The report's line: what was read, and that `--fps` sets the asset's rate.
pub fn text(t: &SourceTime, fps: f64) -> String {
    let mut parts = Vec::new();
    if t.frames > 0 {
        let implied = t.implied_fps.map_or(String::new(), |r| format!(", {} frames per second of that time", short(r, 3)));
        parts.push(format!("{} {} to {} s over {} frame{}{implied}", t.key, short(t.first, 6), short(t.last, 6), t.frames, if t.frames == 1 { "" } else { "s" }));
    }
    if let Some(r) = t.stated_fps {
        parts.push(format!("a frame rate of {}", short(r, 3)));
    }
    format!("the sources' metadata states {}; the asset plays at {fps} fps (--fps)", parts.join(" and "))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn statements_add_up() {
        let t = |v: f64| Stated { time: Some(("simulation_time", v)), fps: None };
        let s = summarize(&[t(0.0), Stated::default(), t(1.0 / 60.0), t(2.0 / 60.0)]).unwrap();
        assert_eq!((s.key.as_str(), s.frames, s.stated_fps), ("simulation_time", 3, None));
        assert!((s.implied_fps.unwrap() - 60.0).abs() < 1e-9);
        assert!(text(&s, 24.0).contains("simulation_time 0 to 0.033333 s over 3 frames, 60 frames per second"), "{}", text(&s, 24.0));
        assert_eq!(summarize(&[Stated::default()]), None);
        let r = summarize(&[Stated { time: None, fps: Some(30.0) }]).unwrap();
        assert_eq!((r.frames, r.stated_fps, r.implied_fps), (0, Some(30.0), None));
    }
}

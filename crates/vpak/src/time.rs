//! Time (version 9): each frame's number in its source sequence and the
//! sequence's frame rate, encoded after the metadata record.

use serde::{Deserialize, Serialize};

/// The frames' place in time: each frame's number in the source sequence
/// (`fire_1001.vdb` is frame 1001) and the sequence's frame rate.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Time {
    /// Frames per second, finite and above 0.
    pub fps: f64,
    /// Per frame, its source frame number, strictly increasing.
    pub numbers: Vec<i64>,
}

/// The frame rate of an asset that records none (older than version 9).
pub const DEFAULT_FPS: f64 = 24.0;

impl Time {
    /// Why `self` cannot be the time of `frames` frames, if it cannot.
    pub fn problem(&self, frames: u32) -> Option<String> {
        if !(self.fps.is_finite() && self.fps > 0.0) {
            return Some(format!("a frame rate of {} (expected a finite number above 0)", self.fps));
        }
        if self.numbers.len() != frames as usize {
            return Some(format!("{} frame numbers for {frames} frames", self.numbers.len()));
        }
        self.numbers.windows(2).find(|w| w[0] >= w[1]).map(|w| format!("frame number {} after {} (numbers must increase)", w[1], w[0]))
    }
}

/// Frame numbers as short text: "1001-1240", "1001-1010 step 3", or runs
/// ("1-5, 8, 10-12") when the steps differ.
pub fn numbers_text(numbers: &[i64]) -> String {
    match numbers {
        [] => "none".into(),
        [n] => n.to_string(),
        [a, b, ..] => {
            let step = b - a;
            if numbers.windows(2).all(|w| w[1] - w[0] == step) {
                let last = numbers[numbers.len() - 1];
                return if step == 1 { format!("{a}-{last}") } else { format!("{a}-{last} step {step}") };
            }
            let mut runs: Vec<String> = Vec::new();
            let mut start = 0;
            for i in 1..=numbers.len() {
                if i == numbers.len() || numbers[i] != numbers[i - 1] + 1 {
                    runs.push(if i - 1 == start { numbers[start].to_string() } else { format!("{}-{}", numbers[start], numbers[i - 1]) });
                    start = i;
                }
            }
            runs.join(", ")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn number_texts() {
        assert_eq!(numbers_text(&[1001, 1002, 1003]), "1001-1003");
        assert_eq!(numbers_text(&[1001, 1004, 1007, 1010]), "1001-1010 step 3");
        assert_eq!(numbers_text(&[1, 2, 3, 5, 8, 9]), "1-3, 5, 8-9");
        assert_eq!(numbers_text(&[-2]), "-2");
    }

    #[test]
    fn time_problems() {
        let t = |fps: f64, numbers: Vec<i64>| Time { fps, numbers };
        assert_eq!(t(24.0, vec![1, 2]).problem(2), None);
        assert!(t(0.0, vec![1]).problem(1).is_some());
        assert!(t(f64::NAN, vec![1]).problem(1).is_some());
        assert!(t(24.0, vec![1]).problem(2).is_some());
        assert!(t(24.0, vec![2, 2]).problem(2).is_some());
    }
}

//! The typed settings of a comparison that both `vdbcook` flags and bake
//! manifest keys are built from: the quality gate and the image size. Each
//! value is checked once, when it is parsed or built.

use std::fmt;
use std::str::FromStr;

/// An image size, `WxH`, each 8 to 8192.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Size {
    pub width: u32,
    pub height: u32,
}

impl FromStr for Size {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || format!("invalid size \"{s}\" (expected WxH, e.g. 512x512, each 8 to 8192)");
        let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
        let (w, h) = (w.trim().parse::<u32>().map_err(|_| bad())?, h.trim().parse::<u32>().map_err(|_| bad())?);
        if !(8..=8192).contains(&w) || !(8..=8192).contains(&h) {
            return Err(bad());
        }
        Ok(Size { width: w, height: h })
    }
}

impl fmt::Display for Size {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}x{}", self.width, self.height)
    }
}

impl Default for Size {
    fn default() -> Self {
        Size { width: 512, height: 512 }
    }
}

/// A manifest writes it as the flag's text.
impl<'de> serde::Deserialize<'de> for Size {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

/// The quality gate: budgets every image of a comparison must meet (none set:
/// no gate). Built through [`Gate::new`] or the flag parsers, which check each budget.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Gate {
    pub max_rmse: Option<f64>,
    pub min_psnr: Option<f64>,
    #[serde(default)]
    pub max_flip: Option<f64>,
}

impl Gate {
    /// A gate of checked budgets; the error names the setting (`max_rmse`, `min_psnr`, `max_flip`).
    pub fn new(max_rmse: Option<f64>, min_psnr: Option<f64>, max_flip: Option<f64>) -> Result<Gate, (&'static str, String)> {
        if let Some(Err(m)) = max_rmse.map(rmse_budget) {
            return Err(("max_rmse", m));
        }
        if let Some(Err(m)) = min_psnr.map(psnr_floor) {
            return Err(("min_psnr", m));
        }
        if let Some(Err(m)) = max_flip.map(flip_budget) {
            return Err(("max_flip", m));
        }
        Ok(Gate { max_rmse, min_psnr, max_flip })
    }

    /// Whether any budget is set.
    pub fn is_set(&self) -> bool {
        self.max_rmse.is_some() || self.min_psnr.is_some() || self.max_flip.is_some()
    }

    /// Whether an image of these figures is over budget.
    pub fn fails(&self, rmse: f64, psnr: f64, flip: f64) -> bool {
        self.max_rmse.is_some_and(|x| rmse > x) || self.min_psnr.is_some_and(|y| psnr < y) || self.max_flip.is_some_and(|x| flip > x)
    }

    /// Whether only FLIP is gated (a search then ranks by FLIP).
    pub fn flip_only(&self) -> bool {
        self.max_rmse.is_none() && self.min_psnr.is_none()
    }

    /// The budgets in words: "psnr >= 40 dB, rmse <= 0.01, flip <= 0.05".
    pub fn text(&self) -> String {
        let mut g = Vec::new();
        if let Some(y) = self.min_psnr {
            g.push(format!("psnr >= {y} dB"));
        }
        if let Some(x) = self.max_rmse {
            g.push(format!("rmse <= {x}"));
        }
        if let Some(f) = self.max_flip {
            g.push(format!("flip <= {f}"));
        }
        g.join(", ")
    }
}

/// A FLIP budget (`--max-flip`, `max_flip`): a finite number >= 0 (FLIP errors lie in [0, 1]).
pub fn flip_budget(x: f64) -> Result<f64, String> {
    if x.is_finite() && x >= 0.0 {
        Ok(x)
    } else {
        Err(format!("must be a finite number >= 0, not {x}"))
    }
}

/// An RMSE budget (`--max-rmse`, `max_rmse`): a number >= 0.
pub fn rmse_budget(x: f64) -> Result<f64, String> {
    if x >= 0.0 {
        Ok(x)
    } else {
        Err(format!("must be a number >= 0, not {x}"))
    }
}

/// A PSNR floor (`--min-psnr`, `min_psnr`), in dB: any number but NaN.
pub fn psnr_floor(y: f64) -> Result<f64, String> {
    if y.is_nan() {
        Err(format!("must be a number, not {y}"))
    } else {
        Ok(y)
    }
}

/// A number as a flag gives it.
pub fn parse_number(s: &str) -> Result<f64, String> {
    s.trim().parse::<f64>().map_err(|_| format!("invalid number \"{s}\""))
}

/// Parses a FLIP budget flag.
pub fn parse_flip_budget(s: &str) -> Result<f64, String> {
    flip_budget(parse_number(s)?)
}

/// Parses an RMSE budget flag.
pub fn parse_rmse_budget(s: &str) -> Result<f64, String> {
    rmse_budget(parse_number(s)?)
}

/// Parses a PSNR floor flag.
pub fn parse_psnr_floor(s: &str) -> Result<f64, String> {
    psnr_floor(parse_number(s)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gates_check_their_budgets() {
        assert!(!Gate::default().is_set());
        assert_eq!(Gate::new(Some(-1.0), None, None).unwrap_err().0, "max_rmse");
        assert_eq!(Gate::new(None, Some(f64::NAN), None).unwrap_err().0, "min_psnr");
        assert_eq!(Gate::new(None, None, Some(f64::INFINITY)).unwrap_err().0, "max_flip");
        let g = Gate::new(Some(0.01), Some(40.0), None).unwrap();
        assert_eq!(g.text(), "psnr >= 40 dB, rmse <= 0.01");
        assert!(g.fails(0.02, 50.0, 0.0) && g.fails(0.0, 30.0, 0.0) && !g.fails(0.01, 40.0, 1.0));
        assert_eq!("64x48".parse::<Size>().unwrap(), Size { width: 64, height: 48 });
        assert!("4x4".parse::<Size>().is_err());
    }
}

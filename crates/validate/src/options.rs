//! The typed settings of a comparison that `vdbcook`'s flags and bake
//! manifest keys are both built from: how it looks at the volume
//! ([`Viewing`]) and the quality gate ([`Gate`]). Each value is checked once,
//! when it is parsed or built (`vdbcook_vpak::settings`).

use std::fmt;
use std::str::FromStr;

use vdbcook_vpak::{bounded, settings_group};

/// An image size, `WxH`, each 8 to 8192.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Size {
    width: u32,
    height: u32,
}

impl Size {
    pub const SIDES: std::ops::RangeInclusive<u32> = 8..=8192;

    /// A size of `width` × `height` pixels, each 8 to 8192.
    pub fn new(width: u32, height: u32) -> Result<Size, String> {
        if Self::SIDES.contains(&width) && Self::SIDES.contains(&height) {
            Ok(Size { width, height })
        } else {
            Err(format!("{width}x{height} is not a size (each side 8 to 8192)"))
        }
    }

    pub fn width(self) -> u32 {
        self.width
    }

    pub fn height(self) -> u32 {
        self.height
    }
}

impl FromStr for Size {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || format!("invalid size \"{s}\" (expected WxH, e.g. 512x512, each 8 to 8192)");
        let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
        let (w, h) = (w.trim().parse::<u32>().map_err(|_| bad())?, h.trim().parse::<u32>().map_err(|_| bad())?);
        Size::new(w, h).map_err(|_| bad())
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

vdbcook_vpak::setting_text_by_display!(Size);

/// A manifest writes it as the flag's text.
impl<'de> serde::Deserialize<'de> for Size {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

bounded!(
    /// Cameras orbiting the volume (`--views`, `views`): 1 to 360.
    Views(u32),
    "view count",
    |n| if (1..=360).contains(&n) { Ok(()) } else { Err(format!("{n} is not a view count (expected 1 to 360)")) }
);

bounded!(
    /// An image RMSE budget (`--max-rmse`, `max_rmse`): a number >= 0.
    RmseBudget(f64),
    "number",
    |x| if x >= 0.0 { Ok(()) } else { Err(format!("must be a number >= 0, not {x}")) }
);

bounded!(
    /// An image PSNR floor in dB (`--min-psnr`, `min_psnr`): any number but NaN.
    PsnrFloor(f64),
    "number",
    |y| if y.is_nan() { Err(format!("must be a number, not {y}")) } else { Ok(()) }
);

bounded!(
    /// A mean FLIP budget (`--max-flip`, `max_flip`): a finite number >= 0 (FLIP errors lie in [0, 1]).
    FlipBudget(f64),
    "number",
    |x| if x.is_finite() && x >= 0.0 { Ok(()) } else { Err(format!("must be a finite number >= 0, not {x}")) }
);

impl Views {
    /// Every view index, 0 to the count − 1.
    pub fn count(self) -> usize {
        self.0 as usize
    }
}

settings_group! {
    /// How a comparison looks at the volume: the medium, the cameras and the image size
    /// (flags of `validate`, `render` and `cook`; keys of a bake manifest).
    #[cfg_attr(feature = "clap", derive(clap::Args))]
    pub struct Viewing {
        /// The channel that gives extinction in the validation scene (default: "density", else
        /// the first scalar fog channel that does not glow; see `vdbcook validate --help`).
        #[cfg_attr(feature = "clap", arg(long, value_name = "NAME"))]
        pub extinction: Option<String> = None;
        /// Cameras orbiting the volume (1 to 360).
        #[cfg_attr(feature = "clap", arg(long, value_name = "N", default_value_t = Viewing::default().views))]
        pub views: Views = Views(8);
        /// Image size (each side 8 to 8192).
        #[cfg_attr(feature = "clap", arg(long, value_name = "WxH", default_value_t = Viewing::default().size))]
        pub size: Size = Size::default();
    }
}

settings_group! {
    /// The quality gate: budgets every image of a comparison must meet (none
    /// set: no gate). Each budget checks itself when it is built.
    #[derive(Copy, serde::Serialize, serde::Deserialize)]
    #[cfg_attr(feature = "clap", derive(clap::Args))]
    pub struct Gate {
        /// Exit with code 3 when any image's RMSE is above X.
        #[cfg_attr(feature = "clap", arg(long, value_name = "X", allow_negative_numbers = true))]
        pub max_rmse: Option<RmseBudget> = None;
        /// Exit with code 3 when any image's PSNR (dB) is below Y.
        #[cfg_attr(feature = "clap", arg(long, value_name = "Y", allow_negative_numbers = true))]
        pub min_psnr: Option<PsnrFloor> = None;
        /// Exit with code 3 when any image's mean FLIP error (0 to 1, at 67 pixels per degree) is above F.
        #[cfg_attr(feature = "clap", arg(long, value_name = "F", allow_negative_numbers = true))]
        #[serde(default)]
        pub max_flip: Option<FlipBudget> = None;
    }
}

impl Gate {
    /// Whether any budget is set.
    pub fn is_set(&self) -> bool {
        self.max_rmse.is_some() || self.min_psnr.is_some() || self.max_flip.is_some()
    }

    /// Whether an image of these figures is over budget.
    pub fn fails(&self, rmse: f64, psnr: f64, flip: f64) -> bool {
        self.max_rmse.is_some_and(|x| rmse > x.get()) || self.min_psnr.is_some_and(|y| psnr < y.get()) || self.max_flip.is_some_and(|x| flip > x.get())
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_check_themselves() {
        assert!(!Gate::default().is_set());
        assert!(RmseBudget::new(-1.0).is_err() && "-1".parse::<RmseBudget>().is_err());
        assert!(PsnrFloor::new(f64::NAN).is_err());
        assert!(FlipBudget::new(f64::INFINITY).is_err() && FlipBudget::new(0.0).is_ok());
        let g = Gate { max_rmse: Some(RmseBudget::new(0.01).unwrap()), min_psnr: Some(PsnrFloor::new(40.0).unwrap()), max_flip: None };
        assert_eq!(g.text(), "psnr >= 40 dB, rmse <= 0.01");
        assert!(g.fails(0.02, 50.0, 0.0) && g.fails(0.0, 30.0, 0.0) && !g.fails(0.01, 40.0, 1.0));
        assert_eq!("64x48".parse::<Size>().unwrap(), Size::new(64, 48).unwrap());
        assert!("4x4".parse::<Size>().is_err() && Size::new(8, 8193).is_err());
        assert!(Views::new(0).is_err() && Views::new(361).is_err() && "8".parse::<Views>() == Views::new(8));
        assert_eq!(Viewing::default().views.get(), 8);
    }
}

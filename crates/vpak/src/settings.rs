//! Typed settings, the floor of every crate's options: numbers checked once,
//! when they are built ([`bounded!`]), and groups of settings that clap flags
//! and manifest keys are both built from ([`settings_group!`]). Each crate
//! declares its own types so (levels in this crate; error bounds in encode;
//! views, image sizes and budgets in validate; cook's own in pipeline): a
//! value of such a type is always in range, and nothing downstream checks it
//! again.

/// A setting's value as canonical text: what cache keys hash and metadata
/// records (`None` and an empty list are empty text).
pub trait SettingText {
    fn text(&self) -> String;
}

/// [`SettingText`] for types whose `Display` is the canonical text.
#[macro_export]
macro_rules! setting_text_by_display {
    ($($t:ty),*) => {$( impl $crate::settings::SettingText for $t { fn text(&self) -> String { self.to_string() } } )*};
}
setting_text_by_display!(bool, u32, u64, f32, f64, String);

impl SettingText for crate::Format {
    fn text(&self) -> String {
        self.name().to_string()
    }
}

impl<T: SettingText> SettingText for Option<T> {
    fn text(&self) -> String {
        self.as_ref().map(SettingText::text).unwrap_or_default()
    }
}

impl<T: SettingText> SettingText for Vec<T> {
    fn text(&self) -> String {
        self.iter().map(SettingText::text).collect::<Vec<_>>().join(",")
    }
}

/// What a manifest reader does with one setting's slot: it deserializes the
/// value into it (keeping the value's position, for instance).
pub trait SettingVisitor {
    type Out;
    fn visit<T: serde::de::DeserializeOwned>(self, slot: &mut T) -> Self::Out;
}

/// A group of settings, as [`settings_group!`] declares it.
pub trait Settings: Default {
    /// Appends the settings' names (the manifest keys), in canonical order.
    fn keys(out: &mut Vec<&'static str>);
    /// Whether a setting of the group is named `key`.
    fn has(key: &str) -> bool {
        let mut k = Vec::new();
        Self::keys(&mut k);
        k.contains(&key)
    }
    /// Hands the slot of the setting named `key` to `v`; `None` when there is none.
    fn visit_key<V: SettingVisitor>(&mut self, key: &str, v: V) -> Option<V::Out>;
    /// Sets the setting named `key` to `from`'s value of it.
    fn copy_key(&mut self, from: &Self, key: &str);
    /// Appends every setting as (name, canonical text), in canonical order.
    fn pairs(&self, out: &mut Vec<(&'static str, String)>);
}

/// Declares a struct of settings, each `pub NAME: TYPE = DEFAULT;` with its
/// doc comment and attributes (a crate with clap puts
/// `#[cfg_attr(feature = "clap", arg(...))]` there and derives `clap::Args`
/// on the struct), then `flatten { pub NAME: GROUP; }` for the groups it
/// includes (their settings are its own, flat, in a manifest). Implements
/// `Default` and [`Settings`]. Each value type parses and checks itself
/// (`FromStr` for a flag, `Deserialize` for a manifest): the group checks nothing.
#[macro_export]
macro_rules! settings_group {
    (
        $(#[$meta:meta])*
        pub struct $group:ident {
            $( $(#[$attr:meta])* pub $name:ident : $ty:ty = $default:expr ; )*
        }
        $( flatten { $( $(#[$gattr:meta])* pub $gname:ident : $gty:ty ; )* } )?
    ) => {
        $(#[$meta])*
        #[derive(Clone, Debug, PartialEq)]
        pub struct $group {
            $( $(#[$attr])* pub $name: $ty, )*
            $($( $(#[$gattr])* pub $gname: $gty, )*)?
        }

        impl Default for $group {
            fn default() -> Self {
                $group { $( $name: $default, )* $($( $gname: Default::default(), )*)? }
            }
        }

        impl $crate::settings::Settings for $group {
            fn keys(out: &mut Vec<&'static str>) {
                $( out.push(stringify!($name)); )*
                $($( <$gty as $crate::settings::Settings>::keys(out); )*)?
            }
            fn visit_key<V: $crate::settings::SettingVisitor>(&mut self, key: &str, v: V) -> Option<V::Out> {
                $( if key == stringify!($name) { return Some(v.visit(&mut self.$name)); } )*
                $($( if <$gty as $crate::settings::Settings>::has(key) { return self.$gname.visit_key(key, v); } )*)?
                None
            }
            fn copy_key(&mut self, from: &Self, key: &str) {
                $( if key == stringify!($name) { self.$name = from.$name.clone(); return; } )*
                $($( if <$gty as $crate::settings::Settings>::has(key) { return self.$gname.copy_key(&from.$gname, key); } )*)?
            }
            fn pairs(&self, out: &mut Vec<(&'static str, String)>) {
                $( out.push((stringify!($name), $crate::settings::SettingText::text(&self.$name))); )*
                $($( self.$gname.pairs(out); )*)?
            }
        }
    };
}

/// Declares `pub struct $name($inner)`, a number whose only constructor is `new`, which
/// runs `$check` (`fn($inner) -> Result<(), String>`, the message says what is
/// allowed). Parsing (`FromStr`, the flag) and deserializing (a manifest) go
/// through `new`; `Display` writes the number as a flag takes it.
#[macro_export]
macro_rules! bounded {
    ($(#[$meta:meta])* $name:ident($inner:ty), $what:literal, $check:expr) => {
        $(#[$meta])*
        #[derive(Clone, Copy, Debug, PartialEq, PartialOrd)]
        pub struct $name($inner);

        impl $name {
            /// The value, when it is in range; else what is allowed.
            pub fn new(value: $inner) -> Result<Self, String> {
                let check: fn($inner) -> Result<(), String> = $check;
                check(value).map(|()| $name(value))
            }

            pub fn get(self) -> $inner {
                self.0
            }
        }

        impl std::str::FromStr for $name {
            type Err = String;
            fn from_str(s: &str) -> Result<Self, String> {
                let v = s.trim().parse::<$inner>().map_err(|_| format!(concat!("invalid ", $what, " \"{}\""), s))?;
                Self::new(v)
            }
        }

        impl std::fmt::Display for $name {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                self.0.fmt(f)
            }
        }

        impl<'de> $crate::serde::Deserialize<'de> for $name {
            fn deserialize<D: $crate::serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                let v = <$inner as $crate::serde::Deserialize>::deserialize(d)?;
                Self::new(v).map_err(<D::Error as $crate::serde::de::Error>::custom)
            }
        }

        $crate::setting_text_by_display!($name);

        impl $crate::serde::Serialize for $name {
            fn serialize<S: $crate::serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                $crate::serde::Serialize::serialize(&self.0, s)
            }
        }
    };
}

bounded!(
    /// A level count (`--lods`, `lods`): 1 (the frames alone) to [`crate::MAX_LEVELS`].
    LevelCount(u32),
    "level count",
    |n| match n {
        0 => Err("0 is not a level count: 1 keeps the frames alone, N adds levels 1 to N-1".into()),
        n if n > crate::MAX_LEVELS => Err(format!(
            "{n} is more levels than the tree has: at most {max} (level {top}'s voxels are {scale} source voxels wide, and its bricks span a whole L1 slot)",
            max = crate::MAX_LEVELS,
            top = crate::MAX_LEVELS - 1,
            scale = 1u32 << (crate::MAX_LEVELS - 1)
        )),
        _ => Ok(()),
    }
);

bounded!(
    /// A level of detail (`render --lod`, `validate --lod`, `unpack --lod`): 0 (the
    /// frame itself) to [`crate::MAX_LEVELS`] − 1.
    Level(u32),
    "level",
    |k| if k < crate::MAX_LEVELS { Ok(()) } else { Err(format!("level {k} does not exist (expected 0 to {}: 0 is the frame itself)", crate::MAX_LEVELS - 1)) }
);

bounded!(
    /// A frame rate in frames per second (`--fps`, `fps`): above 0, at most 1000.
    Fps(f64),
    "frame rate",
    |r| if r > 0.0 && r <= 1000.0 { Ok(()) } else { Err(format!("{r} frames per second is not above 0 and at most 1000")) }
);

impl Fps {
    /// 24 frames per second, the rate of film and of most simulation caches.
    pub const DEFAULT: Fps = Fps(crate::DEFAULT_FPS);
}

impl LevelCount {
    /// The frames alone.
    pub const ONE: LevelCount = LevelCount(1);

    /// Levels 0 … `self` − 1.
    pub fn levels(self) -> std::ops::Range<u32> {
        0..self.0
    }
}

impl Level {
    pub const FINEST: Level = Level(0);

    /// The level count that reaches this level (levels 0 to `self`).
    pub fn count(self) -> LevelCount {
        LevelCount(self.0 + 1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_are_checked_once_however_built() {
        assert!(LevelCount::new(0).is_err());
        assert_eq!(LevelCount::new(crate::MAX_LEVELS).map(LevelCount::get), Ok(crate::MAX_LEVELS));
        assert!(LevelCount::new(crate::MAX_LEVELS + 1).unwrap_err().contains("more levels than the tree has"));
        assert_eq!("3".parse::<LevelCount>(), Ok(LevelCount(3)));
        assert_eq!("x".parse::<LevelCount>().unwrap_err(), "invalid level count \"x\"");
        assert!(format!("{}", crate::MAX_LEVELS).parse::<Level>().is_err());
        assert_eq!("0".parse::<Level>(), Ok(Level::FINEST));
        use serde::de::value::{Error, U32Deserializer};
        use serde::Deserialize;
        assert_eq!(LevelCount::deserialize(U32Deserializer::<Error>::new(2)).map(LevelCount::get), Ok(2));
        assert!(LevelCount::deserialize(U32Deserializer::<Error>::new(0)).is_err());
    }
}

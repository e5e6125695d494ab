//! A manifest's tables as written: the settings each gives, with the byte
//! span of every value, read through the settings' own types (one check per
//! value, the same as the flag's) and applied in order: built-in defaults,
//! `[defaults]`, the `[[asset]]` entry.

use crate::options::{CookSettings, Settings};
use serde::de::{DeserializeOwned, DeserializeSeed, Deserializer, Error as _, MapAccess, Visitor};
use serde::Deserialize;
use std::fmt;
use std::ops::Range;
use toml::Spanned;
use vdbcook_vpak::settings::SettingVisitor;

/// The settings one table gives, and where each value is.
#[derive(Clone, Debug, Default)]
pub struct SettingsTable {
    values: CookSettings,
    given: Vec<(String, Range<usize>)>,
}

impl SettingsTable {
    /// Overrides `s` with the settings this table gives.
    pub fn apply(&self, s: &mut CookSettings) {
        for (key, _) in &self.given {
            s.copy_key(&self.values, key);
        }
    }

    /// Where the table gives `name`.
    pub fn span(&self, name: &str) -> Option<Range<usize>> {
        self.given.iter().find(|(k, _)| k == name).map(|(_, s)| s.clone())
    }

    /// Reads one `key = value` (a setting's name) into the table.
    fn read<'de, A: MapAccess<'de>>(&mut self, key: String, map: &mut A) -> Result<(), A::Error> {
        let span = map.next_value_seed(Slot { values: &mut self.values, key: &key })?;
        self.given.push((key, span));
        Ok(())
    }
}

/// One `[[asset]]` entry: name, output, inputs, parts and any setting.
#[derive(Clone, Debug)]
pub struct AssetTable {
    pub name: Spanned<String>,
    pub output: Spanned<String>,
    pub inputs: Spanned<Vec<Spanned<String>>>,
    /// Cook the asset as this many parts (bake units of their own), joined
    /// into the asset: how the work is spread, not a cook setting, so an
    /// asset's own key only (not in `[defaults]`).
    pub parts: Option<Spanned<u32>>,
    pub settings: SettingsTable,
}

impl AssetTable {
    const OWN: [&'static str; 4] = ["name", "output", "inputs", "parts"];
}

/// A key the table knows (else serde's "unknown field" error, at the key).
struct Key(&'static [&'static str]);

impl<'de> DeserializeSeed<'de> for Key {
    type Value = String;
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<String, D::Error> {
        let key = String::deserialize(d)?;
        if self.0.contains(&key.as_str()) {
            Ok(key)
        } else {
            Err(D::Error::unknown_field(&key, self.0))
        }
    }
}

/// The value of one setting, read into its slot by its own type; its span.
struct Slot<'a> {
    values: &'a mut CookSettings,
    key: &'a str,
}

impl<'de> DeserializeSeed<'de> for Slot<'_> {
    type Value = Range<usize>;
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<Range<usize>, D::Error> {
        struct Into<'de, 'k, D>(D, &'k str, std::marker::PhantomData<&'de ()>);
        impl<'de, D: Deserializer<'de>> SettingVisitor for Into<'de, '_, D> {
            type Out = Result<Range<usize>, D::Error>;
            fn visit<T: DeserializeOwned>(self, slot: &mut T) -> Self::Out {
                // The message names the setting, as a flag's names the flag.
                let v = Spanned::<T>::deserialize(self.0).map_err(|e| D::Error::custom(format!("{}: {e}", self.1)))?;
                let span = v.span();
                *slot = v.into_inner();
                Ok(span)
            }
        }
        let key = self.key.to_string();
        self.values.visit_key(self.key, Into(d, self.key, std::marker::PhantomData)).unwrap_or_else(|| Err(D::Error::custom(format!("unknown setting `{key}`"))))
    }
}

/// Every key a table of settings may give, leaked once (serde's errors list them as `&'static`).
fn setting_keys() -> &'static [&'static str] {
    static KEYS: std::sync::OnceLock<Vec<&'static str>> = std::sync::OnceLock::new();
    KEYS.get_or_init(CookSettings::names)
}

fn asset_keys() -> &'static [&'static str] {
    static KEYS: std::sync::OnceLock<Vec<&'static str>> = std::sync::OnceLock::new();
    KEYS.get_or_init(|| AssetTable::OWN.iter().copied().chain(CookSettings::names()).collect())
}

impl<'de> Deserialize<'de> for SettingsTable {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = SettingsTable;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a table of cook settings")
            }
            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<SettingsTable, A::Error> {
                let mut t = SettingsTable::default();
                while let Some(key) = map.next_key_seed(Key(setting_keys()))? {
                    t.read(key, &mut map)?;
                }
                Ok(t)
            }
        }
        d.deserialize_map(V)
    }
}

impl<'de> Deserialize<'de> for AssetTable {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = AssetTable;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("an asset: name, output, inputs, parts and cook settings")
            }
            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<AssetTable, A::Error> {
                let (mut name, mut output, mut inputs, mut parts) = (None, None, None, None);
                let mut settings = SettingsTable::default();
                while let Some(key) = map.next_key_seed(Key(asset_keys()))? {
                    match key.as_str() {
                        "name" => name = Some(map.next_value()?),
                        "output" => output = Some(map.next_value()?),
                        "inputs" => inputs = Some(map.next_value()?),
                        "parts" => parts = Some(map.next_value::<Spanned<u32>>().map_err(|e| A::Error::custom(format!("parts: {e}")))?),
                        _ => settings.read(key, &mut map)?,
                    }
                }
                Ok(AssetTable {
                    name: name.ok_or_else(|| A::Error::missing_field("name"))?,
                    output: output.ok_or_else(|| A::Error::missing_field("output"))?,
                    inputs: inputs.ok_or_else(|| A::Error::missing_field("inputs"))?,
                    parts,
                    settings,
                })
            }
        }
        d.deserialize_map(V)
    }
}

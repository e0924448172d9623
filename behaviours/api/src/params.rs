//! Typed behaviour parameters: a behaviour declares its parameters once, with [`params!`](macro@crate::params),
//! as a struct with a default, a unit and a range per field; `--param key=value` pairs and sweep
//! values are parsed into it by name (each value through serde from its plain text), so an unknown
//! key or a bad value is refused before any robot moves, and `coordinator --list-behaviours`
//! prints the same declaration.

use std::collections::BTreeMap;
use std::fmt;

/// One declared parameter, as `--list-behaviours` and error messages show it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ParamInfo {
    /// The key, as `--param KEY=…` takes it.
    pub name: &'static str,
    /// The Rust type of its value.
    pub ty: &'static str,
    /// The default, as plain text.
    pub default: String,
    /// The allowed range, as plain text (`lo to hi`), when it has one.
    pub range: Option<String>,
    /// The field's doc line: what it is and its unit.
    pub doc: &'static str,
}

impl fmt::Display for ParamInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.default.is_empty() {
            write!(f, "{}=… ({}, unset by default", self.name, self.ty)?;
        } else {
            write!(f, "{}={} ({}", self.name, self.default, self.ty)?;
        }
        if let Some(r) = &self.range {
            write!(f, ", {r}")?;
        }
        write!(f, "): {}", self.doc)
    }
}

/// A parameter refused, naming it.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ParamError {
    /// A key the behaviour does not declare.
    #[error("unknown parameter {key:?} for {behaviour}; {}", accepted(.known))]
    Unknown {
        /// The behaviour.
        behaviour: String,
        /// The key given.
        key: String,
        /// The keys it takes.
        known: Vec<&'static str>,
    },
    /// A value that does not parse as the field's type.
    #[error("parameter {key}={value:?} is not a valid {ty}: {why}")]
    Parse {
        /// The key.
        key: String,
        /// The value given.
        value: String,
        /// The field's type.
        ty: &'static str,
        /// What the parser said.
        why: String,
    },
    /// A value outside the declared range, or refused by the behaviour's own check.
    #[error("parameter {key}={value}: expected {expected}")]
    Range {
        /// The key.
        key: String,
        /// The value.
        value: String,
        /// What it must be.
        expected: String,
    },
}

fn accepted(known: &[&'static str]) -> String {
    if known.is_empty() {
        "it takes no parameters".into()
    } else {
        format!("its parameters: {}", known.join(", "))
    }
}

/// A behaviour's parameters: a struct with a [`Default`], filled from `key=value` text by
/// [`Params::from_pairs`]. Declare one with [`params!`](macro@crate::params) rather than by hand.
pub trait Params: Default + Clone + fmt::Debug + Send + Sync + 'static {
    /// Every parameter, in declaration order.
    fn describe() -> Vec<ParamInfo>;
    /// Sets `key` from its plain text.
    ///
    /// # Errors
    /// An unknown key or a value that does not parse (`behaviour` names the behaviour in it).
    fn set(&mut self, behaviour: &str, key: &str, value: &str) -> Result<(), ParamError>;
    /// Checks every value against its declared range.
    ///
    /// # Errors
    /// The first value out of range.
    fn check(&self) -> Result<(), ParamError>;

    /// The defaults with `pairs` applied, checked.
    ///
    /// # Errors
    /// The first unknown key, unparsable value or value out of range, by name.
    fn from_pairs(behaviour: &str, pairs: &BTreeMap<String, String>) -> Result<Self, ParamError> {
        let mut p = Self::default();
        for (k, v) in pairs {
            p.set(behaviour, k, v)?;
        }
        p.check()?;
        Ok(p)
    }
}

/// Parameters of a behaviour that takes none.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Deserialize)]
pub struct NoParams;

impl Params for NoParams {
    fn describe() -> Vec<ParamInfo> {
        Vec::new()
    }
    fn set(&mut self, behaviour: &str, key: &str, _: &str) -> Result<(), ParamError> {
        Err(ParamError::Unknown {
            behaviour: behaviour.into(),
            key: key.into(),
            known: Vec::new(),
        })
    }
    fn check(&self) -> Result<(), ParamError> {
        Ok(())
    }
}

/// Parses one value from its plain text through serde (numbers, `true`/`false`, unit enum
/// variants by name, strings; an `Option` field takes the inner value).
///
/// # Errors
/// The value does not parse as `T`.
pub fn parse_value<T: serde::de::DeserializeOwned>(
    key: &str,
    value: &str,
    ty: &'static str,
) -> Result<T, ParamError> {
    T::deserialize(PlainOption(serde_plain::Deserializer::new(value))).map_err(|e| {
        ParamError::Parse {
            key: key.into(),
            value: value.into(),
            ty,
            why: e.to_string(),
        }
    })
}

/// A parameter's key: its field's name, without the `r#` of a raw identifier (`r#box` is `box`).
pub fn key(field: &'static str) -> &'static str {
    field.strip_prefix("r#").unwrap_or(field)
}

/// A range bound as text, rounded to 6 decimals when its own text is long (`STOP_GAP_M + 0.01`
/// reads `0.1`, not `0.09999999999999999`).
pub fn bound<T: fmt::Display>(v: T) -> String {
    let text = v.to_string();
    match text.parse::<f64>() {
        Ok(x) if text.len() > 10 && x.fract() != 0.0 => ((x * 1e6).round() / 1e6).to_string(),
        _ => text,
    }
}

/// Plain text for a parameter value, as `--list-behaviours` prints a default.
pub fn plain_text<T: serde::Serialize + fmt::Debug>(v: &T) -> String {
    serde_plain::to_string(v).unwrap_or_else(|_| format!("{v:?}"))
}

/// `serde_plain`'s deserializer, with a present value read as `Some` for an `Option` field.
struct PlainOption<'de>(serde_plain::Deserializer<'de>);

/// Forwards each named `deserialize_*` method, which takes only a visitor, to the inner
/// deserializer.
macro_rules! forward {
    ($($method:ident)*) => {$(
        fn $method<V: serde::de::Visitor<'de>>(self, v: V) -> Result<V::Value, Self::Error> {
            self.0.$method(v)
        }
    )*};
}

impl<'de> serde::Deserializer<'de> for PlainOption<'de> {
    type Error = serde_plain::Error;

    fn deserialize_any<V: serde::de::Visitor<'de>>(self, v: V) -> Result<V::Value, Self::Error> {
        self.0.deserialize_any(v)
    }

    fn deserialize_option<V: serde::de::Visitor<'de>>(self, v: V) -> Result<V::Value, Self::Error> {
        v.visit_some(self.0)
    }

    forward! {
        deserialize_bool deserialize_i8 deserialize_i16 deserialize_i32 deserialize_i64
        deserialize_u8 deserialize_u16 deserialize_u32 deserialize_u64 deserialize_f32
        deserialize_f64 deserialize_char deserialize_str deserialize_string deserialize_bytes
        deserialize_byte_buf deserialize_unit deserialize_seq deserialize_map
        deserialize_identifier deserialize_ignored_any
    }

    fn deserialize_unit_struct<V: serde::de::Visitor<'de>>(
        self,
        name: &'static str,
        v: V,
    ) -> Result<V::Value, Self::Error> {
        self.0.deserialize_unit_struct(name, v)
    }

    fn deserialize_newtype_struct<V: serde::de::Visitor<'de>>(
        self,
        name: &'static str,
        v: V,
    ) -> Result<V::Value, Self::Error> {
        self.0.deserialize_newtype_struct(name, v)
    }

    fn deserialize_tuple<V: serde::de::Visitor<'de>>(
        self,
        len: usize,
        v: V,
    ) -> Result<V::Value, Self::Error> {
        self.0.deserialize_tuple(len, v)
    }

    fn deserialize_tuple_struct<V: serde::de::Visitor<'de>>(
        self,
        name: &'static str,
        len: usize,
        v: V,
    ) -> Result<V::Value, Self::Error> {
        self.0.deserialize_tuple_struct(name, len, v)
    }

    fn deserialize_struct<V: serde::de::Visitor<'de>>(
        self,
        name: &'static str,
        fields: &'static [&'static str],
        v: V,
    ) -> Result<V::Value, Self::Error> {
        self.0.deserialize_struct(name, fields, v)
    }

    fn deserialize_enum<V: serde::de::Visitor<'de>>(
        self,
        name: &'static str,
        variants: &'static [&'static str],
        v: V,
    ) -> Result<V::Value, Self::Error> {
        self.0.deserialize_enum(name, variants, v)
    }
}

/// Declares a behaviour's parameters: a struct deriving `serde::Deserialize` with a `Default`
/// from the declared values, and its [`Params`] implementation. Each field has one doc line
/// (what it is and its unit), its type, its default and optionally an inclusive range
/// (`lo => hi`); an `Option` field defaults to `None` and its range applies to a present value.
///
/// ```
/// behaviour_api::params! {
///     /// Parameters of a spinning behaviour.
///     pub struct SpinParams {
///         /// Wheel speed, m/s.
///         speed: f32 = 0.05, 0.01 => 0.3;
///         /// Turns before the verdict.
///         turns: u32 = 2, 1 => 10;
///     }
/// }
/// use behaviour_api::Params;
/// let p = SpinParams::from_pairs("spin", &[("turns".to_string(), "3".to_string())].into()).unwrap();
/// assert_eq!((p.speed, p.turns), (0.05, 3));
/// let err = SpinParams::from_pairs("spin", &[("turn".to_string(), "3".to_string())].into());
/// assert_eq!(err.unwrap_err().to_string(), "unknown parameter \"turn\" for spin; its parameters: speed, turns");
/// ```
#[macro_export]
macro_rules! params {
    (
        $(#[$meta:meta])*
        $vis:vis struct $name:ident {
            $(
                #[doc = $doc:literal]
                $field:ident : $ty:ty = $default:expr $(, $lo:expr => $hi:expr)? ;
            )*
        }
    ) => {
        $(#[$meta])*
        #[derive(Clone, Debug, PartialEq, $crate::serde::Deserialize)]
        #[serde(crate = "behaviour_api::serde", default, deny_unknown_fields)]
        $vis struct $name {
            $(
                #[doc = $doc]
                pub $field: $ty,
            )*
        }

        impl ::core::default::Default for $name {
            fn default() -> Self {
                Self { $($field: $default,)* }
            }
        }

        impl $crate::Params for $name {
            fn describe() -> ::std::vec::Vec<$crate::ParamInfo> {
                let d = <Self as ::core::default::Default>::default();
                ::std::vec![$(
                    $crate::ParamInfo {
                        name: $crate::params::key(::core::stringify!($field)),
                        ty: ::core::stringify!($ty),
                        default: $crate::params::plain_text(&d.$field),
                        range: $crate::params!(@range $($lo, $hi)?),
                        doc: $doc.trim(),
                    },
                )*]
            }

            fn set(
                &mut self,
                behaviour: &str,
                key: &str,
                value: &str,
            ) -> ::core::result::Result<(), $crate::ParamError> {
                $(
                    if key == $crate::params::key(::core::stringify!($field)) {
                        self.$field = $crate::params::parse_value(
                            key,
                            value,
                            ::core::stringify!($ty),
                        )?;
                        return Ok(());
                    }
                )*
                Err($crate::ParamError::Unknown {
                    behaviour: behaviour.into(),
                    key: key.into(),
                    known: ::std::vec![$($crate::params::key(::core::stringify!($field))),*],
                })
            }

            fn check(&self) -> ::core::result::Result<(), $crate::ParamError> {
                $( $crate::params!(@check self, $field $(, $lo, $hi)?); )*
                Ok(())
            }
        }
    };
    (@range) => { ::core::option::Option::None };
    (@range $lo:expr, $hi:expr) => {
        ::core::option::Option::Some(::std::format!(
            "{} to {}",
            $crate::params::bound($lo),
            $crate::params::bound($hi)
        ))
    };
    (@check $self:ident, $field:ident) => {};
    (@check $self:ident, $field:ident, $lo:expr, $hi:expr) => {
        if let ::core::option::Option::Some(v) = $crate::params::InRange::value(&$self.$field) {
            if !($lo..=$hi).contains(&v) {
                return Err($crate::ParamError::Range {
                    key: $crate::params::key(::core::stringify!($field)).into(),
                    value: ::std::format!("{}", v),
                    expected: ::std::format!(
                        "{} to {}",
                        $crate::params::bound($lo),
                        $crate::params::bound($hi)
                    ),
                });
            }
        }
    };
}

/// A field value a declared range applies to: the value itself, or an `Option`'s content.
pub trait InRange {
    /// The compared value.
    type Value: PartialOrd + fmt::Display;
    /// The value to compare, if there is one.
    fn value(&self) -> Option<Self::Value>;
}

macro_rules! in_range {
    ($($t:ty),*) => {$(
        impl InRange for $t {
            type Value = $t;
            fn value(&self) -> Option<$t> {
                Some(*self)
            }
        }
        impl InRange for Option<$t> {
            type Value = $t;
            fn value(&self) -> Option<$t> {
                *self
            }
        }
    )*};
}
in_range!(f32, f64, u8, u16, u32, u64, usize, i32, i64);

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Clone, Copy, Debug, PartialEq, serde::Deserialize, serde::Serialize)]
    #[serde(rename_all = "lowercase")]
    pub enum Mode {
        Fast,
        Slow,
    }

    crate::params! {
        /// Test parameters.
        pub struct P {
            /// A speed, m/s.
            speed: f64 = 0.1, 0.05 => 0.5;
            /// A count.
            n: Option<u32> = None, 1 => 9;
            /// A mode.
            mode: Mode = Mode::Fast;
            /// A switch.
            on: bool = true;
        }
    }

    fn pairs(p: &[(&str, &str)]) -> BTreeMap<String, String> {
        p.iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect()
    }

    #[test]
    fn values_parse_by_their_type_and_defaults_stay() {
        let p = P::from_pairs(
            "t",
            &pairs(&[("n", "4"), ("mode", "slow"), ("on", "false")]),
        );
        assert_eq!(
            p,
            Ok(P {
                speed: 0.1,
                n: Some(4),
                mode: Mode::Slow,
                on: false
            })
        );
    }

    #[test]
    fn an_unknown_key_is_named_with_the_accepted_keys() {
        let e = P::from_pairs("t", &pairs(&[("bogus", "1")])).unwrap_err();
        assert_eq!(
            e.to_string(),
            "unknown parameter \"bogus\" for t; its parameters: speed, n, mode, on"
        );
        let e = NoParams::from_pairs("teleop", &pairs(&[("speed", "1")])).unwrap_err();
        assert_eq!(
            e.to_string(),
            "unknown parameter \"speed\" for teleop; it takes no parameters"
        );
    }

    #[test]
    fn bad_values_and_values_out_of_range_are_refused_by_name() {
        let e = P::from_pairs("t", &pairs(&[("speed", "fast")])).unwrap_err();
        assert!(
            matches!(&e, ParamError::Parse { key, ty: "f64", .. } if key == "speed"),
            "{e}"
        );
        let e = P::from_pairs("t", &pairs(&[("speed", "0.9")])).unwrap_err();
        assert_eq!(e.to_string(), "parameter speed=0.9: expected 0.05 to 0.5");
        let e = P::from_pairs("t", &pairs(&[("n", "12")])).unwrap_err();
        assert_eq!(e.to_string(), "parameter n=12: expected 1 to 9");
        let e = P::from_pairs("t", &pairs(&[("mode", "medium")])).unwrap_err();
        assert!(matches!(e, ParamError::Parse { .. }), "{e}");
    }

    crate::params! {
        /// A key that is a Rust keyword.
        pub struct Keyword {
            /// A box's width, metres.
            r#box: f64 = 0.04, 0.01 => STOP + 0.01;
        }
    }
    const STOP: f64 = 0.09;

    #[test]
    fn a_keyword_field_is_its_plain_key_and_long_bounds_are_rounded() {
        let p = Keyword::from_pairs("t", &pairs(&[("box", "0.05")])).unwrap();
        assert_eq!(p.r#box, 0.05);
        let e = Keyword::from_pairs("t", &pairs(&[("r#box", "0.05")])).unwrap_err();
        assert_eq!(
            e.to_string(),
            "unknown parameter \"r#box\" for t; its parameters: box"
        );
        let e = Keyword::from_pairs("t", &pairs(&[("box", "0.5")])).unwrap_err();
        assert_eq!(e.to_string(), "parameter box=0.5: expected 0.01 to 0.1");
        assert_eq!(
            Keyword::describe()[0].to_string(),
            "box=0.04 (f64, 0.01 to 0.1): A box's width, metres."
        );
    }

    #[test]
    fn the_declaration_describes_every_parameter() {
        let d = P::describe();
        assert_eq!(d.len(), 4);
        assert_eq!(
            d[0].to_string(),
            "speed=0.1 (f64, 0.05 to 0.5): A speed, m/s."
        );
        assert_eq!(d[1].default, "");
        assert_eq!(
            d[1].to_string(),
            "n=… (Option<u32>, unset by default, 1 to 9): A count."
        );
        assert_eq!(d[2].default, "fast");
        assert_eq!(d[2].range, None);
    }
}

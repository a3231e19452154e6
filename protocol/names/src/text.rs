//! The words of the text enums (laws, presets, modes, paths, statuses): each enum's variants are
//! its one definition. `strum` derives its word (`IntoStaticStr`), its parser (`EnumString`)
//! and its list (`VariantArray`), with the same case rule as its serde derive; [`allowed`](crate::allowed)
//! builds the "allowed: …" list of an error from that list, and [`parse`](crate::parse) the one-line error.

use strum::VariantArray;

/// Declares a text enum: its variants are its words, in one case rule for serde (config files,
/// JSON, CSV) and strum (`name`, `parse`, the "allowed" lists), and `what` names it in a parse
/// error. Adds `ALL`, `name()`, `parse()` (`unknown <what> `x` (allowed: …)`) and `Display` (the word,
/// padded). The crate using it depends on `serde` and `strum`.
///
/// ```
/// deltaloop_names::text_enum! {
///     "kebab-case", "colour";
///     /// A colour.
///     #[derive(Default)]
///     pub enum Colour {
///         #[default]
///         DarkRed,
///         Blue,
///     }
/// }
/// assert_eq!(Colour::DarkRed.name(), "dark-red");
/// assert_eq!(Colour::parse("blue"), Ok(Colour::Blue));
/// assert_eq!(format!("{:>5}", Colour::Blue), " blue");
/// assert_eq!(deltaloop_names::allowed::<Colour>(), "dark-red, blue");
/// ```
#[macro_export]
macro_rules! text_enum {
    ($case:literal, $what:literal; $(#[$meta:meta])* $vis:vis enum $name:ident { $($body:tt)* }) => {
        $(#[$meta])*
        #[derive(
            Clone,
            Copy,
            Debug,
            PartialEq,
            Eq,
            Hash,
            serde::Serialize,
            serde::Deserialize,
            strum::IntoStaticStr,
            strum::VariantArray,
        )]
        #[serde(rename_all = $case)]
        #[strum(serialize_all = $case)]
        $vis enum $name { $($body)* }

        $crate::text_words!($what; $name);
    };
}

/// The words of a text enum another derive declares (strum's `EnumDiscriminants`: the variants
/// of an enum with data, without it): what [`text_enum!`](crate::text_enum) adds (`ALL`,
/// `name()`, `parse()`, `Display`, [`TextEnum`]) to an enum that derives `Copy`,
/// `strum::IntoStaticStr` and `strum::VariantArray` in its case rule.
#[macro_export]
macro_rules! text_words {
    ($what:literal; $name:ident) => {
        impl $name {
            /// Every variant, in declaration order.
            pub const ALL: &'static [Self] = <Self as strum::VariantArray>::VARIANTS;

            /// The word: in config files, on the command line, in JSON and CSV.
            pub fn name(self) -> &'static str {
                self.into()
            }

            /// Parses a word; the error lists the allowed ones.
            pub fn parse(s: &str) -> Result<Self, String> {
                $crate::parse($what, s)
            }
        }

        impl $crate::TextEnum for $name {
            const ALL: &'static [Self] = Self::ALL;
            fn name(self) -> &'static str {
                Self::name(self)
            }
            fn parse(s: &str) -> Result<Self, String> {
                Self::parse(s)
            }
        }

        impl std::fmt::Display for $name {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.pad(self.name())
            }
        }
    };
}

/// What [`text_enum!`](crate::text_enum) gives an enum, for code generic over them (a
/// command-line parser that lists the words, a sweep axis).
pub trait TextEnum: Copy + 'static {
    /// Every variant, in declaration order.
    const ALL: &'static [Self];
    /// The word of a variant.
    fn name(self) -> &'static str;
    /// The variant of a word; else `unknown <what> `s` (allowed: …)`.
    fn parse(s: &str) -> Result<Self, String>;
}

/// The words of every variant of `T`, in declaration order, joined by ", ".
pub fn allowed<T>() -> String
where
    T: VariantArray + Copy + Into<&'static str>,
{
    T::VARIANTS
        .iter()
        .map(|&v| v.into())
        .collect::<Vec<&str>>()
        .join(", ")
}

/// Parses the word of a `T`; else `unknown <what> `s` (allowed: …)`.
pub fn parse<T>(what: &str, s: &str) -> Result<T, String>
where
    T: VariantArray + Copy + Into<&'static str>,
{
    T::VARIANTS
        .iter()
        .copied()
        .find(|&v| v.into() == s)
        .ok_or_else(|| format!("unknown {what} `{s}` (allowed: {})", allowed::<T>()))
}

/// The words of every variant of `T` as a sentence: "a, b, c or d".
pub fn one_of<T>() -> String
where
    T: VariantArray + Copy + Into<&'static str>,
{
    let words: Vec<&str> = T::VARIANTS.iter().map(|&v| v.into()).collect();
    match words.split_last() {
        Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
        _ => words.concat(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Law, Preset};

    /// The lists and errors come from the variants (the serde words are checked against these
    /// in the supervisor, which has a JSON crate).
    #[test]
    fn lists_and_errors_come_from_the_variants() {
        assert_eq!(
            allowed::<Law>(),
            "tdc, tde-is, tdc-is-sta, tdc-is-ista, pid"
        );
        assert_eq!(one_of::<Preset>(), "matched or paper");
        assert_eq!(parse::<Law>("law", "tde-is"), Ok(Law::TdeIs));
        assert_eq!(
            parse::<Law>("law", "lqr"),
            Err("unknown law `lqr` (allowed: tdc, tde-is, tdc-is-sta, tdc-is-ista, pid)".into())
        );
    }
}

//! A text enum's flag (`--law`, `--role`, `--link-path`): parsed by the enum's own words (its
//! error lists them), with the help's possible values taken from its variants, so a new variant
//! appears in the help without a word written.

use deltaloop_names::TextEnum;
use std::marker::PhantomData;

/// The value parser of a flag whose value is a `T`.
pub struct Words<T>(PhantomData<fn() -> T>);

impl<T> Words<T> {
    pub const fn new() -> Self {
        Self(PhantomData)
    }
}

impl<T> Clone for Words<T> {
    fn clone(&self) -> Self {
        Self::new()
    }
}

impl<T: TextEnum + Send + Sync> clap::builder::TypedValueParser for Words<T> {
    type Value = T;

    fn parse_ref(
        &self,
        cmd: &clap::Command,
        arg: Option<&clap::Arg>,
        value: &std::ffi::OsStr,
    ) -> Result<T, clap::Error> {
        let parse: fn(&str) -> Result<T, String> = T::parse;
        parse.parse_ref(cmd, arg, value)
    }

    fn possible_values(
        &self,
    ) -> Option<Box<dyn Iterator<Item = clap::builder::PossibleValue> + '_>> {
        Some(Box::new(
            T::ALL
                .iter()
                .map(|v| clap::builder::PossibleValue::new(v.name())),
        ))
    }
}

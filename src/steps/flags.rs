//! Each step's command-line flags as plain data: the binary turns every [`Flag`] into a clap
//! argument and hands the values back as [`FlagValues`]; each step reads its own. The library
//! knows nothing of clap.

use crate::error::{Error, Result};
use crate::names::Names;
use std::collections::BTreeMap;
use std::fmt::Display;
use std::str::FromStr;

/// Checks one value of a flag: the message a user sees when it is wrong.
pub type Check = fn(&str) -> std::result::Result<(), String>;

/// One flag of a step.
#[derive(Debug, Clone, Copy)]
pub struct Flag {
    /// The long name without dashes (`blur-window`), also its clap id and the parameter name
    /// of its errors.
    pub long: &'static str,
    /// The value's name in help (`W`); None for a switch.
    pub value_name: Option<&'static str>,
    /// One line of help.
    pub help: &'static str,
    /// The value when the flag is not given.
    pub default: Option<&'static str>,
    /// The values allowed, each with its help (empty: any value `check` accepts).
    pub choices: fn() -> Vec<(&'static str, &'static str)>,
    /// Comma-separated values, the flag repeatable.
    pub list: bool,
    /// A flag this one cannot be given with.
    pub conflicts: Option<&'static str>,
    /// Checks one value, with the message a user sees.
    pub check: Option<Check>,
    /// The step parameter it sets (step id, key): that parameter's errors name this flag.
    pub sets: Option<(&'static str, &'static str)>,
}

impl Flag {
    /// A switch.
    pub const fn switch(long: &'static str, help: &'static str) -> Flag {
        Flag {
            long,
            value_name: None,
            help,
            default: None,
            choices: Vec::new,
            list: false,
            conflicts: None,
            check: None,
            sets: None,
        }
    }

    /// A flag taking a value that parses as `T`.
    pub const fn value<T: FromStr>(
        long: &'static str,
        name: &'static str,
        help: &'static str,
    ) -> Flag
    where
        T::Err: Display,
    {
        Flag {
            value_name: Some(name),
            check: Some(parses::<T>),
            ..Flag::switch(long, help)
        }
    }

    /// With a default value.
    pub const fn default(self, value: &'static str) -> Flag {
        Flag {
            default: Some(value),
            ..self
        }
    }

    /// Its values are the names of `T`.
    pub const fn choices<T: Names>(self) -> Flag {
        let choices = T::choices;
        Flag { choices, ..self }
    }

    /// Comma-separated and repeatable.
    pub const fn list(self) -> Flag {
        Flag { list: true, ..self }
    }

    /// Not to be given with `other`.
    pub const fn conflicts(self, other: &'static str) -> Flag {
        Flag {
            conflicts: Some(other),
            ..self
        }
    }

    /// Sets the parameter `key` of the step `step`.
    pub const fn sets(self, step: &'static str, key: &'static str) -> Flag {
        Flag {
            sets: Some((step, key)),
            ..self
        }
    }
}

fn parses<T: FromStr>(s: &str) -> std::result::Result<(), String>
where
    T::Err: Display,
{
    s.parse::<T>().map(|_| ()).map_err(|e| e.to_string())
}

/// The values given for the step flags (defaults filled in), by long name; a switch given holds
/// no value.
#[derive(Debug, Default, Clone)]
pub struct FlagValues(BTreeMap<&'static str, Vec<String>>);

impl FlagValues {
    /// Records `long` as given with `values`.
    pub fn set(&mut self, long: &'static str, values: Vec<String>) {
        self.0.insert(long, values);
    }

    /// Whether `long` was given (or has a default).
    pub fn given(&self, long: &str) -> bool {
        self.0.contains_key(long)
    }

    /// The value of `long`, parsed.
    pub fn get<T: FromStr>(&self, long: &str) -> Result<Option<T>>
    where
        T::Err: Display,
    {
        Ok(self.list(long)?.into_iter().next())
    }

    /// Every value of `long`, parsed.
    pub fn list<T: FromStr>(&self, long: &str) -> Result<Vec<T>>
    where
        T::Err: Display,
    {
        let values = self.0.get(long).map(Vec::as_slice).unwrap_or_default();
        values
            .iter()
            .map(|v| {
                v.parse()
                    .map_err(|e| Error::param(long, format!("`{v}`: {e}")))
            })
            .collect()
    }
}

//! One table of names per enum of values that users type and files record (backends, metrics,
//! formats, …): parsing, printing, serde and the command line's possible values all read it, so
//! each name is spelled once and every reader refuses an unknown one with the same message.

/// `(name, value, help)` of each value, in the order help lists them.
pub type Table<T> = &'static [(&'static str, T, &'static str)];

/// An enum whose values have names, from one table.
pub trait Names: Sized + Copy + PartialEq + 'static {
    /// The flag that takes these names, without dashes (`backend`): a refusal names it as clap
    /// does, so the command line, workflows and project files say the same.
    const FLAG: &'static str;
    /// The first entry of a value is its name; a later entry of the same value is an alias
    /// (read, never written). An entry whose value carries data (`trimmed-mean`'s trim) stands
    /// for that variant with any data.
    const NAMES: Table<Self>;

    /// The value's name: the entry equal to it, else the first of its variant.
    fn name(self) -> &'static str {
        let variant = |v: &Self| std::mem::discriminant(v) == std::mem::discriminant(&self);
        let entry = Self::NAMES.iter().find(|e| e.1 == self);
        entry
            .or_else(|| Self::NAMES.iter().find(|e| variant(&e.1)))
            .map_or("", |e| e.0)
    }

    /// The value named `s` (a name or an alias).
    fn from_name(s: &str) -> Result<Self, String> {
        if let Some(e) = Self::NAMES.iter().find(|e| e.0 == s) {
            return Ok(e.1);
        }
        let names: Vec<&str> = Self::choices().iter().map(|c| c.0).collect();
        let (flag, value) = (Self::FLAG, Self::FLAG.to_uppercase().replace('-', "_"));
        let names = names.join(", ");
        Err(format!(
            "invalid value '{s}' for '--{flag} <{value}>' [possible values: {names}]"
        ))
    }

    /// `(name, help)` of each value, aliases left out.
    fn choices() -> Vec<(&'static str, &'static str)> {
        let entries = Self::NAMES.iter().filter(|e| e.1.name() == e.0);
        entries.map(|e| (e.0, e.2)).collect()
    }

    /// The aliases of the value named `name`.
    fn aliases(name: &str) -> Vec<&'static str> {
        let entries = Self::NAMES
            .iter()
            .filter(|e| e.0 != name && e.1.name() == name);
        entries.map(|e| e.0).collect()
    }
}

/// `FromStr` and `Display` from the type's [`Names`] table; with `serde`, also `Serialize` and
/// `Deserialize` as the same strings.
macro_rules! impl_names {
    ($t:ty) => {
        impl std::str::FromStr for $t {
            type Err = String;
            fn from_str(s: &str) -> std::result::Result<Self, String> {
                <$t as $crate::names::Names>::from_name(s)
            }
        }

        impl std::fmt::Display for $t {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str($crate::names::Names::name(*self))
            }
        }
    };
    ($t:ty, serde) => {
        $crate::names::impl_names!($t);

        impl serde::Serialize for $t {
            fn serialize<S: serde::Serializer>(
                &self,
                s: S,
            ) -> std::result::Result<S::Ok, S::Error> {
                s.serialize_str($crate::names::Names::name(*self))
            }
        }

        impl<'de> serde::Deserialize<'de> for $t {
            fn deserialize<D: serde::Deserializer<'de>>(
                d: D,
            ) -> std::result::Result<Self, D::Error> {
                let s = <std::borrow::Cow<'de, str>>::deserialize(d)?;
                <$t as $crate::names::Names>::from_name(&s).map_err(serde::de::Error::custom)
            }
        }
    };
}

pub(crate) use impl_names;

/// An enum of unit values declared with its [`Names`] table, each value once:
/// `Variant = "name": "help",` (its doc comment and attributes pass through); with
/// [`impl_names!`]'s impls, serde included.
macro_rules! named_enum {
    (
        $(#[$m:meta])*
        pub enum $t:ident: $flag:literal {
            $($(#[$vm:meta])* $v:ident = $name:literal: $help:literal,)+
        }
    ) => {
        $(#[$m])*
        pub enum $t {
            $($(#[$vm])* $v,)+
        }

        impl $crate::names::Names for $t {
            const FLAG: &'static str = $flag;
            const NAMES: $crate::names::Table<Self> = &[$(($name, $t::$v, $help)),+];
        }
        $crate::names::impl_names!($t, serde);
    };
}

pub(crate) use named_enum;

#[cfg(test)]
mod tests {
    use super::Names;

    #[derive(Debug, Clone, Copy, PartialEq)]
    enum Shape {
        Dot,
        Ring { r: u32 },
    }

    impl Names for Shape {
        const FLAG: &'static str = "shape-kind";
        const NAMES: super::Table<Self> = &[
            ("dot", Shape::Dot, "A dot"),
            ("ring-1", Shape::Ring { r: 1 }, "A thin ring"),
            ("ring", Shape::Ring { r: 2 }, "A ring"),
            ("thin-ring", Shape::Ring { r: 1 }, "A thin ring"),
        ];
    }

    #[test]
    fn names_aliases_and_variants_with_other_data() {
        assert_eq!(Shape::Ring { r: 1 }.name(), "ring-1");
        assert_eq!(Shape::Ring { r: 2 }.name(), "ring");
        // No entry holds r = 5: the first entry of its variant names it.
        assert_eq!(Shape::Ring { r: 5 }.name(), "ring-1");
        assert_eq!(Shape::from_name("thin-ring"), Ok(Shape::Ring { r: 1 }));
        let names: Vec<&str> = Shape::choices().iter().map(|c| c.0).collect();
        assert_eq!(names, ["dot", "ring-1", "ring"]);
        assert_eq!(Shape::aliases("ring-1"), ["thin-ring"]);
        assert!(Shape::aliases("dot").is_empty());
        assert_eq!(
            Shape::from_name("square"),
            Err("invalid value 'square' for '--shape-kind <SHAPE_KIND>' \
                 [possible values: dot, ring-1, ring]"
                .to_string())
        );
    }
}

//! Reading JSON the way users write it: an object is an object.
//!
//! serde's derived structs also accept a JSON array of their fields in declaration order, so
//! `"camera": [[0, 0, 4], [0, 0, 0]]` was read as a camera's first two fields, and a wrong
//! array gave a message about its elements (`camera[0]: expected a string`) or about a Rust type
//! (`expected struct Camera with 8 elements`). [`Objects`] wraps a deserializer so that every
//! struct, at any depth, is read from a JSON object only; [`plain_message`] says serde's
//! messages in JSON's words. [`Objects`] reads scene files, glTF files and job requests;
//! [`plain_message`] words the errors of every request body and query string too.
//!
//! A struct inside an internally tagged or untagged enum (a shape or a material of the scene
//! format) is read by serde from its buffered content, past the wrapper: such a value can still
//! be an array of its fields.

use serde::de::{self, DeserializeSeed, Deserializer, Visitor};
use std::fmt;

/// A deserializer that reads structs from maps (JSON objects) only, at every depth.
pub struct Objects<D>(pub D);

/// Deserializes `T` from `de`, every struct from a JSON object only.
pub fn from_objects<'de, T: serde::Deserialize<'de>, D: Deserializer<'de>>(
    de: D,
) -> Result<T, D::Error> {
    T::deserialize(Objects(de))
}

/// `T` read with [`from_objects`]: a wrapper for places that take any `Deserialize` type (a
/// web framework's JSON body extractor).
#[derive(Debug)]
pub struct Strict<T>(pub T);

impl<'de, T: serde::Deserialize<'de>> serde::Deserialize<'de> for Strict<T> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        from_objects(d).map(Strict)
    }
}

macro_rules! forward {
    ($($method:ident)*) => {
        $(
            fn $method<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Self::Error> {
                self.0.$method(Wrap(visitor))
            }
        )*
    };
}

impl<'de, D: Deserializer<'de>> Deserializer<'de> for Objects<D> {
    type Error = D::Error;

    forward! {
        deserialize_any deserialize_bool deserialize_i8 deserialize_i16 deserialize_i32
        deserialize_i64 deserialize_i128 deserialize_u8 deserialize_u16 deserialize_u32
        deserialize_u64 deserialize_u128 deserialize_f32 deserialize_f64 deserialize_char
        deserialize_str deserialize_string deserialize_bytes deserialize_byte_buf
        deserialize_option deserialize_unit deserialize_seq deserialize_map
        deserialize_identifier deserialize_ignored_any
    }

    fn deserialize_unit_struct<V: Visitor<'de>>(
        self,
        name: &'static str,
        visitor: V,
    ) -> Result<V::Value, Self::Error> {
        self.0.deserialize_unit_struct(name, Wrap(visitor))
    }

    fn deserialize_newtype_struct<V: Visitor<'de>>(
        self,
        name: &'static str,
        visitor: V,
    ) -> Result<V::Value, Self::Error> {
        self.0.deserialize_newtype_struct(name, Wrap(visitor))
    }

    fn deserialize_tuple<V: Visitor<'de>>(
        self,
        len: usize,
        visitor: V,
    ) -> Result<V::Value, Self::Error> {
        self.0.deserialize_tuple(len, Wrap(visitor))
    }

    fn deserialize_tuple_struct<V: Visitor<'de>>(
        self,
        name: &'static str,
        len: usize,
        visitor: V,
    ) -> Result<V::Value, Self::Error> {
        self.0.deserialize_tuple_struct(name, len, Wrap(visitor))
    }

    fn deserialize_struct<V: Visitor<'de>>(
        self,
        name: &'static str,
        fields: &'static [&'static str],
        visitor: V,
    ) -> Result<V::Value, Self::Error> {
        if name.starts_with("$serde_json") {
            // serde_json's own markers (raw values, arbitrary-precision numbers).
            return self.0.deserialize_struct(name, fields, Wrap(visitor));
        }
        self.0.deserialize_map(Wrap(visitor))
    }

    /// An enum is a string naming a variant, or an object of one variant and its value; read
    /// through `deserialize_any`, so that anything else is "invalid type: integer `3`, expected
    /// one of `a`, `b`" rather than serde_json's bare "expected value".
    fn deserialize_enum<V: Visitor<'de>>(
        self,
        _name: &'static str,
        variants: &'static [&'static str],
        visitor: V,
    ) -> Result<V::Value, Self::Error> {
        self.0.deserialize_any(EnumOf { visitor, variants })
    }

    fn is_human_readable(&self) -> bool {
        self.0.is_human_readable()
    }
}

/// Reads an enum from what the document holds: a string (a unit variant) or a map (one
/// variant and its value).
struct EnumOf<V> {
    visitor: V,
    variants: &'static [&'static str],
}

impl<'de, V: Visitor<'de>> Visitor<'de> for EnumOf<V> {
    type Value = V::Value;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        let names: Vec<String> = self.variants.iter().map(|v| format!("`{v}`")).collect();
        match names.len() {
            0 => f.write_str("nothing (this value has no possible choices)"),
            1 => write!(f, "{}", names[0]),
            _ => write!(f, "one of {}", names.join(", ")),
        }
    }

    fn visit_str<E: de::Error>(self, v: &str) -> Result<Self::Value, E> {
        self.visitor
            .visit_enum(de::value::StrDeserializer::<E>::new(v))
    }

    fn visit_borrowed_str<E: de::Error>(self, v: &'de str) -> Result<Self::Value, E> {
        self.visitor
            .visit_enum(de::value::BorrowedStrDeserializer::<E>::new(v))
    }

    fn visit_string<E: de::Error>(self, v: String) -> Result<Self::Value, E> {
        self.visit_str(&v)
    }

    fn visit_map<A: de::MapAccess<'de>>(self, mut map: A) -> Result<Self::Value, A::Error> {
        let value = self.visitor.visit_enum(OneMember(Wrap(&mut map)))?;
        match map.next_key::<String>()? {
            None => Ok(value),
            Some(second) => Err(de::Error::custom(format!(
                "expected an object of one member (the choice), found a second member `{second}`"
            ))),
        }
    }
}

/// An enum read from an object of one member: its name is the choice, its value the choice's
/// settings. An empty object is refused in those words here, a second member by
/// [`EnumOf::visit_map`] (serde's own reader let the JSON parser refuse it as a "trailing
/// comma").
struct OneMember<A>(A);

impl<'de, A: de::MapAccess<'de>> OneMember<A> {
    fn value<T: DeserializeSeed<'de>>(mut self, seed: T) -> Result<T::Value, A::Error> {
        self.0.next_value_seed(seed)
    }
}

impl<'de, A: de::MapAccess<'de>> de::EnumAccess<'de> for OneMember<A> {
    type Error = A::Error;
    type Variant = Self;

    fn variant_seed<V: DeserializeSeed<'de>>(
        mut self,
        seed: V,
    ) -> Result<(V::Value, Self), A::Error> {
        match self.0.next_key_seed(seed)? {
            Some(choice) => Ok((choice, self)),
            None => Err(de::Error::custom(
                "expected an object of one member (the choice), found an empty object",
            )),
        }
    }
}

impl<'de, A: de::MapAccess<'de>> de::VariantAccess<'de> for OneMember<A> {
    type Error = A::Error;

    fn unit_variant(self) -> Result<(), A::Error> {
        self.value(std::marker::PhantomData::<()>)
    }

    fn newtype_variant_seed<T: DeserializeSeed<'de>>(self, seed: T) -> Result<T::Value, A::Error> {
        self.value(seed)
    }

    fn tuple_variant<V: Visitor<'de>>(self, len: usize, visitor: V) -> Result<V::Value, A::Error> {
        self.value(Tuple(len, visitor))
    }

    fn struct_variant<V: Visitor<'de>>(
        self,
        fields: &'static [&'static str],
        visitor: V,
    ) -> Result<V::Value, A::Error> {
        self.value(Struct(fields, visitor))
    }
}

/// A seed that reads a tuple of this length with this visitor.
struct Tuple<V>(usize, V);

impl<'de, V: Visitor<'de>> DeserializeSeed<'de> for Tuple<V> {
    type Value = V::Value;

    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<V::Value, D::Error> {
        d.deserialize_tuple(self.0, self.1)
    }
}

/// A seed that reads a struct of these fields with this visitor.
struct Struct<V>(&'static [&'static str], V);

impl<'de, V: Visitor<'de>> DeserializeSeed<'de> for Struct<V> {
    type Value = V::Value;

    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<V::Value, D::Error> {
        d.deserialize_struct("", self.0, self.1)
    }
}

/// A visitor whose nested deserializers are wrapped in [`Objects`].
struct Wrap<V>(V);

macro_rules! visit {
    ($($method:ident: $ty:ty)*) => {
        $(
            fn $method<E: de::Error>(self, v: $ty) -> Result<Self::Value, E> {
                self.0.$method(v)
            }
        )*
    };
}

impl<'de, V: Visitor<'de>> Visitor<'de> for Wrap<V> {
    type Value = V::Value;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        self.0.expecting(f)
    }

    visit! {
        visit_bool: bool visit_i8: i8 visit_i16: i16 visit_i32: i32 visit_i64: i64
        visit_i128: i128 visit_u8: u8 visit_u16: u16 visit_u32: u32 visit_u64: u64
        visit_u128: u128 visit_f32: f32 visit_f64: f64 visit_char: char visit_str: &str
        visit_borrowed_str: &'de str visit_string: String visit_bytes: &[u8]
        visit_borrowed_bytes: &'de [u8] visit_byte_buf: Vec<u8>
    }

    fn visit_none<E: de::Error>(self) -> Result<Self::Value, E> {
        self.0.visit_none()
    }

    fn visit_unit<E: de::Error>(self) -> Result<Self::Value, E> {
        self.0.visit_unit()
    }

    fn visit_some<D: Deserializer<'de>>(self, d: D) -> Result<Self::Value, D::Error> {
        self.0.visit_some(Objects(d))
    }

    fn visit_newtype_struct<D: Deserializer<'de>>(self, d: D) -> Result<Self::Value, D::Error> {
        self.0.visit_newtype_struct(Objects(d))
    }

    fn visit_seq<A: de::SeqAccess<'de>>(self, seq: A) -> Result<Self::Value, A::Error> {
        self.0.visit_seq(Wrap(seq))
    }

    fn visit_map<A: de::MapAccess<'de>>(self, map: A) -> Result<Self::Value, A::Error> {
        self.0.visit_map(Wrap(map))
    }

    fn visit_enum<A: de::EnumAccess<'de>>(self, data: A) -> Result<Self::Value, A::Error> {
        self.0.visit_enum(Wrap(data))
    }
}

impl<'de, S: DeserializeSeed<'de>> DeserializeSeed<'de> for Wrap<S> {
    type Value = S::Value;

    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<Self::Value, D::Error> {
        self.0.deserialize(Objects(d))
    }
}

impl<'de, A: de::SeqAccess<'de>> de::SeqAccess<'de> for Wrap<A> {
    type Error = A::Error;

    fn next_element_seed<T: DeserializeSeed<'de>>(
        &mut self,
        seed: T,
    ) -> Result<Option<T::Value>, Self::Error> {
        self.0.next_element_seed(Wrap(seed))
    }

    fn size_hint(&self) -> Option<usize> {
        self.0.size_hint()
    }
}

impl<'de, A: de::MapAccess<'de>> de::MapAccess<'de> for Wrap<A> {
    type Error = A::Error;

    fn next_key_seed<K: DeserializeSeed<'de>>(
        &mut self,
        seed: K,
    ) -> Result<Option<K::Value>, Self::Error> {
        self.0.next_key_seed(Wrap(seed))
    }

    fn next_value_seed<T: DeserializeSeed<'de>>(
        &mut self,
        seed: T,
    ) -> Result<T::Value, Self::Error> {
        self.0.next_value_seed(Wrap(seed))
    }

    fn size_hint(&self) -> Option<usize> {
        self.0.size_hint()
    }
}

impl<'de, A: de::EnumAccess<'de>> de::EnumAccess<'de> for Wrap<A> {
    type Error = A::Error;
    type Variant = Wrap<A::Variant>;

    fn variant_seed<T: DeserializeSeed<'de>>(
        self,
        seed: T,
    ) -> Result<(T::Value, Self::Variant), Self::Error> {
        let (value, variant) = self.0.variant_seed(Wrap(seed))?;
        Ok((value, Wrap(variant)))
    }
}

impl<'de, A: de::VariantAccess<'de>> de::VariantAccess<'de> for Wrap<A> {
    type Error = A::Error;

    fn unit_variant(self) -> Result<(), Self::Error> {
        self.0.unit_variant()
    }

    fn newtype_variant_seed<T: DeserializeSeed<'de>>(
        self,
        seed: T,
    ) -> Result<T::Value, Self::Error> {
        self.0.newtype_variant_seed(Wrap(seed))
    }

    fn tuple_variant<V: Visitor<'de>>(
        self,
        len: usize,
        visitor: V,
    ) -> Result<V::Value, Self::Error> {
        self.0.tuple_variant(len, Wrap(visitor))
    }

    fn struct_variant<V: Visitor<'de>>(
        self,
        fields: &'static [&'static str],
        visitor: V,
    ) -> Result<V::Value, Self::Error> {
        self.0.struct_variant(fields, Wrap(visitor))
    }
}

/// A JSON object's members, read so that a member given twice is an error ("duplicate field
/// `spp`") rather than the last one silently winning, as `serde_json::Map` lets it.
#[derive(Debug, Default)]
pub struct Members(pub serde_json::Map<String, serde_json::Value>);

impl<'de> serde::Deserialize<'de> for Members {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Members;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("an object")
            }
            fn visit_map<A: de::MapAccess<'de>>(self, map: A) -> Result<Members, A::Error> {
                read_members(map).map(Members)
            }
        }
        d.deserialize_map(V)
    }
}

/// The members of the object `map` reads, refusing a member given twice ("duplicate field
/// `spp`"), for a visitor's `visit_map`.
pub fn read_members<'de, A: de::MapAccess<'de>>(
    mut map: A,
) -> Result<serde_json::Map<String, serde_json::Value>, A::Error> {
    let mut out = serde_json::Map::new();
    while let Some(key) = map.next_key::<String>()? {
        if out.contains_key(&key) {
            return Err(de::Error::custom(format!("duplicate field `{key}`")));
        }
        let value = map.next_value()?;
        out.insert(key, value);
    }
    Ok(out)
}

/// serde's message in the words of JSON: an array, not a sequence; an object, not a map or
/// `struct Camera` (a Rust type a user never wrote).
pub fn plain_message(message: &str) -> String {
    let mut out = String::with_capacity(message.len());
    let mut rest = message;
    while let Some(i) = rest.find("expected struct ") {
        out.push_str(&rest[..i]);
        out.push_str("expected an object");
        let after = &rest[i + "expected struct ".len()..];
        let after = after.strip_prefix("variant ").unwrap_or(after);
        // The type's name (`Camera`, `Foo::Bar` for a struct variant) and serde's length
        // suffix (" with 8 elements") go.
        let name_end = after
            .find(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':'))
            .unwrap_or(after.len());
        rest = &after[name_end..];
        if let Some(tail) = rest.strip_prefix(" with ") {
            if let Some(j) = tail.find(" element") {
                let after = &tail[j + " element".len()..];
                let after = after.strip_prefix('s').unwrap_or(after);
                if tail[..j].bytes().all(|b| b.is_ascii_digit()) {
                    rest = after;
                }
            }
        }
    }
    out.push_str(rest);
    // Rust's number types, as serde names them.
    for (rust, json) in [
        ("f32", "a number"),
        ("f64", "a number"),
        ("u8", "an integer from 0 to 255"),
        ("u16", "an integer from 0 to 65535"),
        ("u32", "an integer from 0 to 4294967295"),
        ("u64", "a non-negative integer"),
        ("usize", "a non-negative integer"),
        ("i32", "an integer from -2147483648 to 2147483647"),
        ("i64", "an integer"),
    ] {
        // serde_json may have put the place after it.
        let (body, place) = match out.find(" at line ") {
            Some(i) => out.split_at(i),
            None => (out.as_str(), ""),
        };
        if let Some(head) = body.strip_suffix(&format!("expected {rust}")) {
            out = format!("{head}expected {json}{place}");
            break;
        }
    }
    // serde's words for an array longer than its value: serde_json's reader says "trailing
    // characters", a JSON value tree "invalid length N, expected fewer elements in array".
    if out == "trailing characters"
        || out.starts_with("invalid length ") && out.ends_with(", expected fewer elements in array")
    {
        // serde_json's word for an array with elements after the ones a value takes.
        return "too many elements: the array is longer than expected".into();
    }
    out.replace("invalid type: sequence", "invalid type: array")
        .replace("invalid type: map", "invalid type: object")
        .replace("expected a sequence", "expected an array")
        .replace("expected a map", "expected an object")
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;

    #[derive(Debug, Deserialize, PartialEq)]
    #[serde(deny_unknown_fields)]
    struct Camera {
        position: [f32; 3],
        fov: Option<f32>,
    }

    #[derive(Debug, Deserialize, PartialEq)]
    struct File {
        camera: Camera,
        cameras: Option<Vec<Camera>>,
        #[serde(default)]
        kind: Kind,
    }

    #[derive(Debug, Default, Deserialize, PartialEq)]
    #[serde(rename_all = "snake_case", deny_unknown_fields)]
    enum Kind {
        #[default]
        Plain,
        Scaled(f32),
        Boxed {
            size: f32,
        },
    }

    fn read(text: &str) -> Result<File, String> {
        let mut de = serde_json::Deserializer::from_str(text);
        serde_path_to_error::deserialize(Objects(&mut de)).map_err(
            |e: serde_path_to_error::Error<serde_json::Error>| {
                let inner = e.inner().to_string();
                let msg = inner.split(" at line ").next().unwrap_or(&inner);
                format!("{}: {}", e.path(), plain_message(msg))
            },
        )
    }

    #[test]
    fn structs_are_read_from_objects_at_every_depth() {
        let ok = read(
            r#"{"camera": {"position": [0, 0, 4]}, "cameras": [{"position": [1, 2, 3],
            "fov": 40}], "kind": {"boxed": {"size": 2}}}"#,
        )
        .unwrap();
        assert_eq!(ok.camera.position, [0.0, 0.0, 4.0]);
        assert_eq!(ok.cameras.unwrap()[0].fov, Some(40.0));
        assert_eq!(ok.kind, Kind::Boxed { size: 2.0 });
        assert_eq!(
            read(r#"{"camera": {"position": [0, 0, 4]}, "kind": {"scaled": 2}}"#)
                .unwrap()
                .kind,
            Kind::Scaled(2.0)
        );
        assert_eq!(
            read(r#"{"camera": {"position": [0, 0, 4]}, "kind": "plain"}"#)
                .unwrap()
                .kind,
            Kind::Plain
        );
        // Without the wrapper serde takes an array of the fields in order.
        let lax: File =
            serde_json::from_str(r#"{"camera": [[0, 0, 4], 30], "cameras": null}"#).unwrap();
        assert_eq!(lax.camera.fov, Some(30.0));
        assert_eq!(
            read(r#"{"camera": [[0, 0, 4], 30]}"#).unwrap_err(),
            "camera: invalid type: array, expected an object"
        );
        assert_eq!(
            read(r#"{"camera": {"position": [0, 0, 4]}, "cameras": [[[1, 2, 3]]]}"#).unwrap_err(),
            "cameras[0]: invalid type: array, expected an object"
        );
        assert_eq!(
            read(r#"[{"position": [0, 0, 4]}]"#).unwrap_err(),
            ".: invalid type: array, expected an object"
        );
        assert_eq!(
            read(r#"{"camera": {"position": [0, 0, 4, 1]}}"#).unwrap_err(),
            "camera.position: too many elements: the array is longer than expected"
        );
        // Other messages keep their words; unknown fields are still refused inside.
        assert_eq!(
            read(r#"{"camera": {"position": [0, 0, 4], "fvo": 3}}"#).unwrap_err(),
            "camera.fvo: unknown field `fvo`, expected `position` or `fov`"
        );
        assert_eq!(
            read(r#"{"camera": {"position": "x"}}"#).unwrap_err(),
            "camera.position: invalid type: string \"x\", expected an array of length 3"
        );
    }

    #[test]
    fn enums_are_named_by_strings_or_objects() {
        assert_eq!(
            read(r#"{"camera": {"position": [0, 0, 4]}, "kind": 3}"#).unwrap_err(),
            "kind: invalid type: integer `3`, expected one of `plain`, `scaled`, `boxed`"
        );
        assert_eq!(
            read(r#"{"camera": {"position": [0, 0, 4]}, "kind": "boxy"}"#).unwrap_err(),
            "kind: unknown variant `boxy`, expected one of `plain`, `scaled`, `boxed`"
        );
        // One member names the choice: a second, or none, is refused in those words.
        assert_eq!(
            read(
                r#"{"camera": {"position": [0, 0, 4]}, "kind": {"scaled": 2, "boxed": {"size": 1}}}"#
            )
            .unwrap_err(),
            "kind: expected an object of one member (the choice), found a second member `boxed`"
        );
        assert_eq!(
            read(r#"{"camera": {"position": [0, 0, 4]}, "kind": {"plain": null, "x": 1}}"#)
                .unwrap_err(),
            "kind: expected an object of one member (the choice), found a second member `x`"
        );
        assert_eq!(
            read(r#"{"camera": {"position": [0, 0, 4]}, "kind": {}}"#).unwrap_err(),
            "kind: expected an object of one member (the choice), found an empty object"
        );
        // A choice without settings may be an object naming it with null.
        assert_eq!(
            read(r#"{"camera": {"position": [0, 0, 4]}, "kind": {"plain": null}}"#)
                .unwrap()
                .kind,
            Kind::Plain
        );
        // A struct variant's fields: an object, and its unknown fields refused.
        assert_eq!(
            read(r#"{"camera": {"position": [0, 0, 4]}, "kind": {"boxed": {"size": 1, "x": 1}}}"#)
                .unwrap_err(),
            "kind.boxed.x: unknown field `x`, expected `size`"
        );
        let v: serde_json::Value = serde_json::from_str(
            r#"{"camera": {"position": [0, 0, 4]},
            "kind": {"scaled": 2}}"#,
        )
        .unwrap();
        assert_eq!(from_objects::<File, _>(&v).unwrap().kind, Kind::Scaled(2.0));
        let v: serde_json::Value =
            serde_json::from_str(r#"{"camera": {"position": [0, 0, 4]}, "kind": "plain"}"#)
                .unwrap();
        assert_eq!(from_objects::<File, _>(&v).unwrap().kind, Kind::Plain);
    }

    #[test]
    fn a_value_tree_is_read_the_same() {
        let v: serde_json::Value = serde_json::from_str(r#"{"camera": [[0, 0, 4]]}"#).unwrap();
        let e = from_objects::<File, _>(&v).unwrap_err().to_string();
        assert_eq!(plain_message(&e), "invalid type: array, expected an object");
    }

    #[test]
    fn messages_name_json_not_rust() {
        let cases = [
            (
                "invalid length 2, expected struct RenderDefaults with 8 elements",
                "invalid length 2, expected an object",
            ),
            (
                "invalid type: sequence, expected struct Camera",
                "invalid type: array, expected an object",
            ),
            (
                "invalid type: map, expected a sequence",
                "invalid type: object, expected an array",
            ),
            (
                "invalid length 1, expected struct variant Kind::Boxed with 1 element",
                "invalid length 1, expected an object",
            ),
            ("missing field `fov`", "missing field `fov`"),
            (
                "invalid type: string \"x\", expected f32",
                "invalid type: string \"x\", expected a number",
            ),
            (
                "invalid type: string \"x\", expected u32 at line 1 column 28",
                "invalid type: string \"x\", expected an integer from 0 to 4294967295 at line 1 \
                 column 28",
            ),
            (
                "invalid value: integer `-1`, expected u32",
                "invalid value: integer `-1`, expected an integer from 0 to 4294967295",
            ),
            (
                "trailing characters",
                "too many elements: the array is longer than expected",
            ),
            (
                "invalid length 4, expected fewer elements in array",
                "too many elements: the array is longer than expected",
            ),
            (
                "invalid length 0, expected struct RegisterRequest with 3 elements at line 1 column 2",
                "invalid length 0, expected an object at line 1 column 2",
            ),
        ];
        for (serde, plain) in cases {
            assert_eq!(plain_message(serde), plain, "{serde}");
        }
    }
}

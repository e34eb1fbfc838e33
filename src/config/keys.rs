//! The keys pipeline.toml accepts, read from the raw sections' serde
//! derives, so that the documentation can be checked against the parser.

use serde::de::{DeserializeOwned, Visitor};

use super::sections::{
    RawAlignment, RawColumns, RawDetect, RawDiagnose, RawSite, RawTopic, RawTransfer, RawVector, RawVectorCalibration,
};
use super::{campaign::RawCampaign, RawFilter, RawFit, RawFlight, RawGradient, RawOutput, RawPipeline, RawQuality};

/// The tables whose keys are names the user chooses, not settings.
pub const MAP_TABLES: [&str; 2] = ["sensor_positions", "model.channels"];

/// Every table of pipeline.toml with the keys it accepts: `""` for the top
/// level (whose keys are the sections), then each section by its dotted
/// path (`"fit"`, `"quality.transfer"`, `"columns.vector"`,
/// `"flight.windows"`). `[sensor_positions]` maps sensor names and
/// `[model] channels` the model's channels, so they have no fixed keys and
/// an empty list ([`MAP_TABLES`]). Any other key is an error.
pub fn accepted_keys() -> Vec<(&'static str, &'static [&'static str])> {
    vec![
        ("", field_names::<RawPipeline>()),
        ("columns", field_names::<RawColumns>()),
        ("columns.vector", field_names::<crate::formats::VectorColumns>()),
        ("alignment", field_names::<RawAlignment>()),
        ("topic", field_names::<RawTopic>()),
        ("filter", field_names::<RawFilter>()),
        ("fit", field_names::<RawFit>()),
        ("output", field_names::<RawOutput>()),
        ("model", field_names::<super::RawModel>()),
        ("model.channels", &[]),
        ("detect", field_names::<RawDetect>()),
        ("quality", field_names::<RawQuality>()),
        ("quality.transfer", field_names::<RawTransfer>()),
        ("diagnose", field_names::<RawDiagnose>()),
        ("vector_calibration", field_names::<RawVectorCalibration>()),
        ("vector", field_names::<RawVector>()),
        ("site", field_names::<RawSite>()),
        ("gradient", field_names::<RawGradient>()),
        ("sensor_positions", &[]),
        ("flight", field_names::<RawFlight>()),
        (
            "flight.windows",
            field_names::<crate::calibration::windows::CalibrationWindow>(),
        ),
        ("campaign", field_names::<RawCampaign>()),
    ]
}

/// The field names a struct's derived `Deserialize` asks for: a
/// deserializer that records them from `deserialize_struct` and reads
/// nothing.
fn field_names<T: DeserializeOwned>() -> &'static [&'static str] {
    let mut names: &'static [&'static str] = &[];
    let _ = T::deserialize(FieldNames(&mut names));
    names
}

struct FieldNames<'a>(&'a mut &'static [&'static str]);

impl<'de> serde::Deserializer<'de> for FieldNames<'_> {
    type Error = serde::de::value::Error;

    fn deserialize_any<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Self::Error> {
        Err(serde::de::Error::custom("not a struct"))
    }

    fn deserialize_struct<V: Visitor<'de>>(
        self,
        _: &'static str,
        fields: &'static [&'static str],
        _: V,
    ) -> Result<V::Value, Self::Error> {
        *self.0 = fields;
        Err(serde::de::Error::custom("field names read"))
    }

    serde::forward_to_deserialize_any! {
        bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string
        bytes byte_buf option unit unit_struct newtype_struct seq tuple
        tuple_struct map enum identifier ignored_any
    }
}

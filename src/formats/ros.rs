//! ROS 2 messages in MCAP (rosbag2 recordings): `sensor_msgs/msg/MagneticField`,
//! `Imu` and `NavSatFix`, CDR-encoded.
//!
//! CDR (XCDR1) starts with a 4-byte encapsulation header whose second byte
//! says little (1) or big (0) endian; every primitive is aligned to its size
//! relative to the end of that header. The three message layouts are fixed
//! by their ROS definitions, so they are decoded directly:
//! - `MagneticField`: the field in tesla, returned in nT;
//! - `Imu`: the orientation quaternion (ROS REP-103: body x forward, y left,
//!   z up, in an east-north-up world), returned as SGL attitude in degrees:
//!   roll right wing down, pitch nose up, yaw clockwise from north;
//! - `NavSatFix`: latitude, longitude (degrees) and altitude (m).

use nalgebra::{Quaternion, UnitQuaternion};

/// The ROS 2 message types magcomp reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RosType {
    /// `sensor_msgs/msg/MagneticField`.
    MagneticField,
    /// `sensor_msgs/msg/Imu`.
    Imu,
    /// `sensor_msgs/msg/NavSatFix`.
    NavSatFix,
}

impl RosType {
    /// The type of a schema name such as `sensor_msgs/msg/Imu`.
    pub fn from_schema_name(name: &str) -> Option<Self> {
        match name.trim_start_matches('/').replace("/msg/", "/").as_str() {
            "sensor_msgs/MagneticField" => Some(RosType::MagneticField),
            "sensor_msgs/Imu" => Some(RosType::Imu),
            "sensor_msgs/NavSatFix" => Some(RosType::NavSatFix),
            _ => None,
        }
    }

    /// Names of the values [`decode`] returns, in order.
    pub fn fields(self) -> &'static [&'static str] {
        match self {
            RosType::MagneticField => &["x_nt", "y_nt", "z_nt"],
            RosType::Imu => &["roll_deg", "pitch_deg", "yaw_deg"],
            RosType::NavSatFix => &["latitude", "longitude", "altitude"],
        }
    }
}

/// A cursor over a CDR payload.
struct Cdr<'a> {
    body: &'a [u8],
    at: usize,
    little: bool,
}

impl<'a> Cdr<'a> {
    fn new(data: &'a [u8]) -> Result<Self, String> {
        if data.len() < 4 {
            return Err("shorter than the CDR encapsulation header".into());
        }
        let little = match data[1] {
            0 => false,
            1 => true,
            other => return Err(format!("unknown CDR encapsulation {other}")),
        };
        Ok(Cdr {
            body: &data[4..],
            at: 0,
            little,
        })
    }

    fn take(&mut self, size: usize) -> Result<&'a [u8], String> {
        self.at = self.at.div_ceil(size.min(8)) * size.min(8);
        let bytes = self
            .body
            .get(self.at..self.at + size)
            .ok_or_else(|| "the message ends early".to_string())?;
        self.at += size;
        Ok(bytes)
    }

    fn u32(&mut self) -> Result<u32, String> {
        let b: [u8; 4] = self.take(4)?.try_into().map_err(|_| "bad u32")?;
        Ok(if self.little {
            u32::from_le_bytes(b)
        } else {
            u32::from_be_bytes(b)
        })
    }

    fn f64(&mut self) -> Result<f64, String> {
        let b: [u8; 8] = self.take(8)?.try_into().map_err(|_| "bad f64")?;
        Ok(if self.little {
            f64::from_le_bytes(b)
        } else {
            f64::from_be_bytes(b)
        })
    }

    fn skip_header(&mut self) -> Result<(), String> {
        self.u32()?; // stamp.sec
        self.u32()?; // stamp.nanosec
        let length = self.u32()? as usize; // frame_id, with its null
        let end = self.at.checked_add(length).filter(|&e| e <= self.body.len());
        self.at = end.ok_or("the frame_id runs past the message")?;
        Ok(())
    }

    fn skip_f64(&mut self, count: usize) -> Result<(), String> {
        (0..count).try_for_each(|_| self.f64().map(|_| ()))
    }
}

/// Decodes one CDR message of type `kind` into `values` (see
/// [`RosType::fields`]).
pub fn decode(kind: RosType, data: &[u8], values: &mut [f64]) -> Result<(), String> {
    let mut cdr = Cdr::new(data)?;
    cdr.skip_header()?;
    match kind {
        RosType::MagneticField => {
            for value in values.iter_mut().take(3) {
                *value = cdr.f64()? * 1e9;
            }
        }
        RosType::Imu => {
            let q = [cdr.f64()?, cdr.f64()?, cdr.f64()?, cdr.f64()?];
            let [roll, pitch, yaw] = sgl_attitude_deg(q);
            values[..3].copy_from_slice(&[roll, pitch, yaw]);
        }
        RosType::NavSatFix => {
            cdr.take(1)?; // status.status
            cdr.take(2)?; // status.service
            for value in values.iter_mut().take(3) {
                *value = cdr.f64()?;
            }
            cdr.skip_f64(9)?;
        }
    }
    Ok(())
}

/// SGL attitude (roll right wing down, pitch nose up, yaw clockwise from
/// north; degrees) from a REP-103 quaternion `[x, y, z, w]` (body FLU in
/// ENU). Roll keeps its sign, pitch changes sign (FLU pitch is nose down),
/// and heading is 90° − the ENU yaw.
pub fn sgl_attitude_deg([x, y, z, w]: [f64; 4]) -> [f64; 3] {
    // Roll, pitch and yaw of the ZYX (yaw, then pitch, then roll)
    // rotation, the quaternion normalised first.
    let orientation = UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z));
    let (roll, pitch, yaw) = orientation.euler_angles();
    let heading = (90.0 - yaw.to_degrees()).rem_euclid(360.0);
    [roll.to_degrees(), -pitch.to_degrees(), heading]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Quaternion of yaw ψ, pitch θ, roll φ (ZYX, FLU in ENU).
    fn quaternion(roll: f64, pitch: f64, yaw: f64) -> [f64; 4] {
        let (cr, sr) = ((roll / 2.0).cos(), (roll / 2.0).sin());
        let (cp, sp) = ((pitch / 2.0).cos(), (pitch / 2.0).sin());
        let (cy, sy) = ((yaw / 2.0).cos(), (yaw / 2.0).sin());
        [
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy,
        ]
    }

    #[test]
    fn rep103_attitude_becomes_sgl_attitude() {
        // Level, nose east: ENU yaw 0 is heading 90°.
        let [roll, pitch, heading] = sgl_attitude_deg(quaternion(0.0, 0.0, 0.0));
        assert!(roll.abs() < 1e-12 && pitch.abs() < 1e-12 && (heading - 90.0).abs() < 1e-12);
        // Nose north (ENU yaw +90°), nose up 5° (FLU pitch −5°), right wing
        // down 10° (FLU roll +10°).
        let q = quaternion(10f64.to_radians(), -5f64.to_radians(), 90f64.to_radians());
        let [roll, pitch, heading] = sgl_attitude_deg(q);
        assert!((roll - 10.0).abs() < 1e-9, "{roll}");
        assert!((pitch - 5.0).abs() < 1e-9, "{pitch}");
        assert!(heading.abs() < 1e-9 || (heading - 360.0).abs() < 1e-9, "{heading}");
        // Nose west: heading 270°.
        let [_, _, heading] = sgl_attitude_deg(quaternion(0.0, 0.0, 180f64.to_radians()));
        assert!((heading - 270.0).abs() < 1e-9, "{heading}");
    }

    #[test]
    fn magnetic_field_in_both_byte_orders() {
        for little in [true, false] {
            let mut data = vec![0, u8::from(little), 0, 0];
            let put_u32 = |d: &mut Vec<u8>, v: u32| d.extend(if little { v.to_le_bytes() } else { v.to_be_bytes() });
            put_u32(&mut data, 12);
            put_u32(&mut data, 500);
            put_u32(&mut data, 4);
            data.extend(b"imu\0");
            for v in [2.0e-5, -1.5e-6, 4.8e-5] {
                data.extend(if little {
                    f64::to_le_bytes(v)
                } else {
                    f64::to_be_bytes(v)
                });
            }
            let mut values = [0.0; 3];
            decode(RosType::MagneticField, &data, &mut values).unwrap();
            assert!((values[0] - 20_000.0).abs() < 1e-9 && (values[2] - 48_000.0).abs() < 1e-9);
            assert!(decode(RosType::MagneticField, &data[..20], &mut values).is_err());
        }
    }
}

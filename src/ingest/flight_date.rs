//! The day a flight was flown (UTC), for absolute times.
//!
//! Survey logs keep time as seconds of the day (SGL `tt`), with the day in
//! `year` and `doy` columns or nowhere. Formats with absolute time (MCAP's
//! `log_time`, nanoseconds since 1970-01-01) need the day: a flight written
//! without it would show as flown on 1 January 1970.
//!
//! Day counts use the proleptic Gregorian calendar (Richards, "Mapping
//! Time", 1998; the days-from-civil form of Hinnant's `chrono` notes).

use std::fmt;

/// A calendar day, UTC.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, serde::Serialize, serde::Deserialize)]
pub struct FlightDate {
    /// Year, e.g. 2020.
    pub year: i32,
    /// Month, 1–12.
    pub month: u32,
    /// Day of the month, 1–31.
    pub day: u32,
}

/// Seconds in a day.
pub const SECONDS_PER_DAY: f64 = 86_400.0;

impl FlightDate {
    /// Parses `YYYY-MM-DD`; `None` when it is not a real day.
    pub fn parse(text: &str) -> Option<Self> {
        let mut parts = text.trim().splitn(3, '-');
        let year = parts.next()?.parse().ok()?;
        let month = parts.next()?.parse().ok()?;
        let day = parts.next()?.parse().ok()?;
        let date = FlightDate { year, month, day };
        let valid = (1..=12).contains(&month) && day >= 1 && day <= days_in_month(year, month);
        (valid && (1900..=9999).contains(&year)).then_some(date)
    }

    /// The `day_of_year`-th day (1 = 1 January) of `year`.
    pub fn from_day_of_year(year: i32, day_of_year: u32) -> Option<Self> {
        if !(1900..=9999).contains(&year) {
            return None;
        }
        let mut remaining = day_of_year;
        for month in 1..=12 {
            let length = days_in_month(year, month);
            if remaining >= 1 && remaining <= length {
                return Some(FlightDate {
                    year,
                    month,
                    day: remaining,
                });
            }
            remaining = remaining.checked_sub(length)?;
        }
        None
    }

    /// Days from 1970-01-01 to this day.
    pub fn days_since_unix_epoch(self) -> i64 {
        let year = i64::from(self.year) - i64::from(self.month <= 2);
        let era = year.div_euclid(400);
        let year_of_era = year - era * 400;
        let month = i64::from(self.month);
        let day_of_year = (153 * (month + if month > 2 { -3 } else { 9 }) + 2) / 5 + i64::from(self.day) - 1;
        let day_of_era = year_of_era * 365 + year_of_era / 4 - year_of_era / 100 + day_of_year;
        era * 146_097 + day_of_era - 719_468
    }

    /// The day `days` after 1970-01-01.
    pub fn from_days_since_unix_epoch(days: i64) -> Self {
        let shifted = days + 719_468;
        let era = shifted.div_euclid(146_097);
        let day_of_era = shifted - era * 146_097;
        let year_of_era = (day_of_era - day_of_era / 1460 + day_of_era / 36_524 - day_of_era / 146_096) / 365;
        let day_of_year = day_of_era - (365 * year_of_era + year_of_era / 4 - year_of_era / 100);
        let month_index = (5 * day_of_year + 2) / 153;
        let day = (day_of_year - (153 * month_index + 2) / 5 + 1) as u32;
        let month = if month_index < 10 {
            month_index + 3
        } else {
            month_index - 9
        } as u32;
        let year = (year_of_era + era * 400 + i64::from(month <= 2)) as i32;
        FlightDate { year, month, day }
    }

    /// Nanoseconds from 1970-01-01 to this day's midnight, UTC.
    pub fn midnight_unix_ns(self) -> i128 {
        i128::from(self.days_since_unix_epoch()) * 86_400 * 1_000_000_000
    }
}

impl fmt::Display for FlightDate {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:04}-{:02}-{:02}", self.year, self.month, self.day)
    }
}

fn is_leap(year: i32) -> bool {
    (year % 4 == 0 && year % 100 != 0) || year % 400 == 0
}

fn days_in_month(year: i32, month: u32) -> u32 {
    match month {
        2 if is_leap(year) => 29,
        2 => 28,
        4 | 6 | 9 | 11 => 30,
        _ => 31,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn days_match_the_calendar() {
        let date = |text| FlightDate::parse(text).unwrap();
        assert_eq!(date("1970-01-01").days_since_unix_epoch(), 0);
        assert_eq!(date("2000-03-01").days_since_unix_epoch(), 11_017);
        // MagNav's flight 1002: 2020-06-20, day 172 of a leap year.
        assert_eq!(FlightDate::from_day_of_year(2020, 172), Some(date("2020-06-20")));
        assert_eq!(date("2020-06-20").days_since_unix_epoch(), 18_433);
        assert_eq!(date("2020-06-20").midnight_unix_ns(), 1_592_611_200_000_000_000);
        for days in (-800_000..800_000).step_by(997) {
            let day = FlightDate::from_days_since_unix_epoch(days);
            assert_eq!(day.days_since_unix_epoch(), days, "{day}");
        }
        assert_eq!(date("2024-02-29").to_string(), "2024-02-29");
        for bad in ["2023-02-29", "2020-13-01", "2020-00-10", "20-06-20x", "", "2020/06/20"] {
            assert_eq!(FlightDate::parse(bad), None, "{bad}");
        }
        assert_eq!(FlightDate::from_day_of_year(2021, 366), None);
        assert_eq!(
            FlightDate::from_day_of_year(2020, 366)
                .map(|d| d.to_string())
                .as_deref(),
            Some("2020-12-31")
        );
    }
}

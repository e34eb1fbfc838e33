//! The flight path and attitude at the internal rate: calibration boxes
//! with a pilot's manoeuvres, coordinated turns, a transit descent, then
//! survey lines in alternating directions with turbulence.
//!
//! Attitude follows the SGL convention (CONTRACT §1): yaw clockwise from
//! north, pitch nose up, roll right wing down, all in degrees. Positions
//! are metres north and east of the flight's start, and height above ground.

use std::f64::consts::PI;

use crate::calibration::windows::ManoeuvreKind;
use crate::simulate::random::Random;
use crate::simulate::scenario::{parse_omission, parse_weakening, BoxPosition, Coupling, Scenario};

/// Where the aircraft is and how it is oriented at one internal sample.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Pose {
    /// Roll, degrees, right wing down positive.
    pub roll_deg: f64,
    /// Pitch, degrees, nose up positive.
    pub pitch_deg: f64,
    /// Yaw (heading), degrees clockwise from north, unwrapped.
    pub yaw_deg: f64,
    /// Metres north of the start.
    pub northing_m: f64,
    /// Metres east of the start.
    pub easting_m: f64,
    /// Height above ground, m.
    pub height_agl_m: f64,
    /// Survey line number, 0 off the lines.
    pub line: f64,
}

/// One manoeuvre as flown: the oscillation from its first to last sample.
#[derive(Debug, Clone, PartialEq)]
pub struct FlownManoeuvre {
    /// Pitch, roll or yaw.
    pub kind: ManoeuvreKind,
    /// Leg heading, degrees.
    pub heading_deg: f64,
    /// Start, s after the flight's start.
    pub t_start_s: f64,
    /// End, s after the flight's start.
    pub t_end_s: f64,
    /// Whole cycles flown.
    pub cycles: usize,
    /// Peak angle, degrees.
    pub amplitude_deg: f64,
    /// Period, s.
    pub period_s: f64,
}

/// A stretch of the flight, in s after the start.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stretch {
    /// Start, s.
    pub t_start_s: f64,
    /// End, s.
    pub t_end_s: f64,
}

/// The whole flight at the internal rate.
#[derive(Debug, Clone, PartialEq)]
pub struct FlightPath {
    /// Internal sample interval, s.
    pub dt_s: f64,
    /// One pose per internal sample.
    pub poses: Vec<Pose>,
    /// Manoeuvres in flying order.
    pub manoeuvres: Vec<FlownManoeuvre>,
    /// Each calibration box.
    pub boxes: Vec<Stretch>,
    /// Each survey line, with its number and heading.
    pub lines: Vec<(f64, f64, Stretch)>,
}

/// Flies the scenario's plan: the boxes before, between or after the
/// survey lines (`[calibration] position`), each joined to the next stage
/// by a transit, or the last leg running straight on into a line.
pub fn fly(scenario: &Scenario, random: &mut Random) -> FlightPath {
    let raw = &scenario.raw;
    let box_ = &raw.calibration;
    let survey = &raw.survey;
    let dt_s = 1.0 / (raw.sample_rate_hz * raw.oversampling as f64);
    let lines = survey.line_count;
    let lines_before = match (box_.position, box_.repeats) {
        (_, 0) | (BoxPosition::Start, _) => 0,
        (BoxPosition::Middle, _) => lines / 2,
        (BoxPosition::End, _) => lines,
    };
    let mut pilot = Pilot {
        dt_s,
        random,
        turbulence: [[0.0; 3]; 2],
        wander: (0.0, 0.0),
        pose: starting_pose(scenario, lines_before),
        path: FlightPath {
            dt_s,
            poses: Vec::new(),
            manoeuvres: Vec::new(),
            boxes: Vec::new(),
            lines: Vec::new(),
        },
    };
    if lines_before > 0 {
        pilot.fly_lines(scenario, 0..lines_before, survey.line_heading_deg);
    }
    if box_.repeats > 0 && pilot.pose.height_agl_m != box_.altitude_m {
        pilot.climb_to_box(scenario);
    }
    let continues = box_.continue_into_survey && lines_before < lines && box_.repeats > 0;
    for repeat in 0..box_.repeats {
        pilot.pose.line = box_.line_numbers.get(repeat).copied().unwrap_or(0.0);
        pilot.fly_box(scenario, !(continues && repeat + 1 == box_.repeats));
        pilot.pose.line = 0.0;
    }
    if lines_before < lines {
        let heading = pilot.pose.yaw_deg.rem_euclid(360.0);
        match continues {
            // Straight on: down to survey height and onto the next line
            // with no turn, so the line's heading is the leg's.
            true => {
                pilot.change_height(survey.altitude_m, heading, survey.speed_m_s, 0.3);
                let base = (heading - 180.0 * (lines_before % 2) as f64).rem_euclid(360.0);
                pilot.fly_lines(scenario, lines_before..lines, base);
            }
            false => {
                let next = (survey.line_heading_deg + 180.0 * (lines_before % 2) as f64).rem_euclid(360.0);
                pilot.transit(scenario, next);
                pilot.fly_lines(scenario, lines_before..lines, survey.line_heading_deg);
            }
        }
    }
    pilot.path
}

/// Where the flight starts: at the box's height when it starts in the box
/// (else at survey height), heading along the box's first leg when no line
/// is flown before it (`lines_before`; else along the lines).
/// The manoeuvres flown on the leg at `heading_deg`, in order, each with
/// the fraction of its amplitude: pitch, roll and yaw less those the crew
/// forgets, then the leg's extra ones.
fn leg_plan(box_: &crate::simulate::scenario::Calibration, heading_deg: f64) -> Vec<(ManoeuvreKind, f64)> {
    let on_leg = |h: f64| (h - heading_deg).abs() < 0.5;
    let omitted: Vec<(ManoeuvreKind, f64)> = box_.omit.iter().filter_map(|o| parse_omission(o).ok()).collect();
    let weakened: Vec<(ManoeuvreKind, f64, f64)> = box_.weaken.iter().filter_map(|w| parse_weakening(w).ok()).collect();
    let extra: Vec<(ManoeuvreKind, f64)> = box_.extra.iter().filter_map(|o| parse_omission(o).ok()).collect();
    [ManoeuvreKind::Pitch, ManoeuvreKind::Roll, ManoeuvreKind::Yaw]
        .into_iter()
        .filter(|&kind| !omitted.iter().any(|(k, h)| *k == kind && on_leg(*h)))
        .map(|kind| {
            let fraction = (weakened.iter())
                .find(|(k, h, _)| *k == kind && on_leg(*h))
                .map_or(1.0, |w| w.2);
            (kind, fraction)
        })
        .chain((extra.iter()).filter(|(_, h)| on_leg(*h)).map(|e| (e.0, 1.0)))
        .collect()
}

fn starting_pose(scenario: &Scenario, lines_before: usize) -> Pose {
    let (box_, survey) = (&scenario.raw.calibration, &scenario.raw.survey);
    let starts_in_box = lines_before == 0 && box_.repeats > 0 && !box_.climb_before;
    Pose {
        height_agl_m: match starts_in_box {
            true => box_.altitude_m,
            false => survey.altitude_m,
        },
        yaw_deg: match lines_before {
            0 => box_.headings_deg.first().copied().unwrap_or(0.0),
            _ => survey.line_heading_deg,
        },
        ..Pose::default()
    }
}

/// The pilot: appends poses to the path.
struct Pilot<'r> {
    dt_s: f64,
    random: &'r mut Random,
    /// Gust drive and the attitude's response to it, degrees (roll, pitch, yaw).
    turbulence: [[f64; 3]; 2],
    /// Slow drift of a loosely held heading, degrees, and its size.
    wander: (f64, f64),
    pose: Pose,
    path: FlightPath,
}

impl Pilot<'_> {
    fn now(&self) -> f64 {
        self.path.poses.len() as f64 * self.dt_s
    }

    fn samples(&self, seconds: f64) -> usize {
        (seconds / self.dt_s).round().max(1.0) as usize
    }

    /// Advances turbulence: a first-order Gauss-Markov gust (1.5 s
    /// correlation, standard deviation `sigma_deg`) that the airframe
    /// follows through its own 0.4 s first-order response, so attitude and
    /// its rates stay smooth, as an aircraft's inertia keeps them.
    fn gust(&mut self, sigma_deg: f64) {
        let keep = (-self.dt_s / 1.5).exp();
        let follow = (-self.dt_s / 0.4).exp();
        let kick = (1.0 - keep * keep).sqrt() * sigma_deg;
        let (offset, size) = self.wander;
        if size > 0.0 {
            let drift = (-self.dt_s / 30.0).exp();
            self.wander.0 = drift * offset + (1.0 - drift * drift).sqrt() * size * self.random.normal();
        } else {
            self.wander.0 = 0.0;
        }
        let [drive, response] = &mut self.turbulence;
        for (axis, share) in [1.0, 0.6, 0.4].iter().enumerate() {
            drive[axis] = keep * drive[axis] + share * kick * self.random.normal();
            response[axis] = follow * response[axis] + (1.0 - follow) * drive[axis];
        }
    }

    /// Records the pose `offset` (roll, pitch, yaw deviation) away from the
    /// nominal heading and moves the aircraft along its yaw at `speed`.
    fn step(&mut self, heading_deg: f64, offset: [f64; 3], speed_m_s: f64) {
        let gust = self.turbulence[1];
        self.pose.roll_deg = offset[0] + gust[0];
        self.pose.pitch_deg = offset[1] + gust[1];
        self.pose.yaw_deg = heading_deg + offset[2] + gust[2] + self.wander.0;
        let track = self.pose.yaw_deg.to_radians();
        self.pose.northing_m += speed_m_s * self.dt_s * track.cos();
        self.pose.easting_m += speed_m_s * self.dt_s * track.sin();
        self.path.poses.push(self.pose);
    }

    fn level(&mut self, seconds: f64, heading_deg: f64, turbulence_deg: f64, speed_m_s: f64) {
        for _ in 0..self.samples(seconds) {
            self.gust(turbulence_deg);
            self.step(heading_deg, [0.0; 3], speed_m_s);
        }
    }

    /// A coordinated turn at `rate_deg_s` with the bank rolled in and out,
    /// the shorter way round.
    fn turn(&mut self, from_deg: f64, to_deg: f64, rate_deg_s: f64, speed_m_s: f64, turbulence_deg: f64) {
        let change = (to_deg - from_deg + 540.0).rem_euclid(360.0) - 180.0;
        self.turn_by(from_deg, change, rate_deg_s, speed_m_s, turbulence_deg);
    }

    /// A coordinated turn through `change` degrees (positive: right).
    fn turn_by(&mut self, from_deg: f64, change: f64, rate_deg_s: f64, speed_m_s: f64, turbulence_deg: f64) {
        let samples = self.samples(change.abs() / rate_deg_s);
        let bank = (speed_m_s * rate_deg_s.to_radians() / 9.81)
            .atan()
            .to_degrees()
            .clamp(10.0, 30.0);
        for k in 0..samples {
            let fraction = (k + 1) as f64 / samples as f64;
            self.gust(turbulence_deg);
            let roll = bank * change.signum() * (PI * fraction).sin().sqrt();
            self.step(from_deg + change * fraction, [roll, 0.0, 0.0], speed_m_s);
        }
    }

    /// A coordinated turn through `change` degrees whose rate builds to
    /// `rate_deg_s` over `entry_s` (a raised cosine) as the bank rolls in,
    /// and dies away the same way as it rolls out: the bank is the
    /// coordinated bank of the rate at each moment, atan(v·ψ̇/g).
    fn banked_turn(
        &mut self,
        from_deg: f64,
        change: f64,
        (rate_deg_s, entry_s): (f64, f64),
        speed_m_s: f64,
        turbulence_deg: f64,
    ) {
        let steady_s = change.abs() / rate_deg_s;
        // A change too small for the full rate is flown with shorter ramps.
        let entry_s = entry_s.min(steady_s);
        let total_s = steady_s + entry_s;
        let samples = self.samples(total_s);
        let dt = total_s / samples as f64;
        let shape = |t: f64| {
            let edge = (t.min(total_s - t) / entry_s.max(1e-9)).clamp(0.0, 1.0);
            0.5 - 0.5 * (PI * edge).cos()
        };
        let mut heading = from_deg;
        // Scaled so that the ramps' sampled sum turns exactly `change`.
        let turned: f64 = (0..samples).map(|k| shape((k as f64 + 0.5) * dt) * dt).sum();
        let scale = change / turned.max(1e-12);
        for k in 0..samples {
            let rate = shape((k as f64 + 0.5) * dt) * scale;
            heading += rate * dt;
            let bank = (speed_m_s * rate.to_radians() / 9.81)
                .atan()
                .to_degrees()
                .clamp(-30.0, 30.0);
            self.gust(turbulence_deg);
            self.step(heading, [bank, 0.0, 0.0], speed_m_s);
        }
    }

    fn manoeuvre(&mut self, scenario: &Scenario, kind: ManoeuvreKind, heading_deg: f64, fraction: f64) {
        let box_ = &scenario.raw.calibration;
        let cycles = self.random.integer(box_.cycles[0], box_.cycles[1]);
        let period_s = self.random.uniform(box_.period_s[0], box_.period_s[1]);
        let nominal = match kind {
            ManoeuvreKind::Pitch => box_.pitch_deg,
            ManoeuvreKind::Roll => box_.roll_deg,
            ManoeuvreKind::Yaw => box_.yaw_deg,
        };
        let amplitude_deg = nominal * self.random.uniform(0.8, 1.2) * fraction;
        let coupled = self.coupled_motion(&box_.coupling, kind);
        let t_start_s = self.now();
        let count = self.samples(cycles as f64 * period_s);
        // The coupled motion fades in and out over half a period, as the
        // airframe's response builds and dies away with the input.
        let fade = (0.5 * period_s / self.dt_s).max(1.0);
        for k in 0..count {
            self.gust(box_.turbulence_deg);
            let phase = 2.0 * PI * (k + 1) as f64 * self.dt_s / period_s;
            let angle = amplitude_deg * phase.sin();
            let mut offset = kind.attitude_offset(angle);
            let edge = ((k + 1).min(count - k) as f64 / fade).min(1.0);
            let taper = 0.5 - 0.5 * (PI * edge).cos();
            for (axis, (share, lag)) in coupled.iter().enumerate() {
                offset[axis] += share * amplitude_deg * taper * (phase - lag).sin();
            }
            self.step(heading_deg, offset, box_.speed_m_s);
        }
        self.path.manoeuvres.push(FlownManoeuvre {
            kind,
            heading_deg,
            t_start_s,
            t_end_s: self.now() - self.dt_s,
            cycles,
            amplitude_deg,
            period_s,
        });
    }

    /// The other axes' motion during a `kind` manoeuvre: per axis (roll,
    /// pitch, yaw) its signed share of the driven amplitude and its phase
    /// lag, radians. Adverse yaw opposes the roll; the roll in a yaw follows
    /// it. Nothing is drawn where the coupling's ranges are zero, so plans
    /// without coupling fly as before.
    fn coupled_motion(&mut self, coupling: &Coupling, kind: ManoeuvreKind) -> [(f64, f64); 3] {
        let mut shares = [(0.0, 0.0); 3];
        let drawn: &[(usize, [f64; 2], f64)] = match kind {
            ManoeuvreKind::Pitch => &[(0, coupling.pitch_roll, 1.0)],
            ManoeuvreKind::Roll => &[(1, coupling.roll_pitch, 1.0), (2, coupling.roll_yaw, -1.0)],
            ManoeuvreKind::Yaw => &[(0, coupling.yaw_roll, 1.0)],
        };
        for &(axis, range, sign) in drawn {
            if range[1] > 0.0 {
                let share = sign * self.draw(range);
                let lag = self.draw(coupling.lag_deg).to_radians();
                shares[axis] = (share, lag);
            }
        }
        shares
    }

    /// A draw from `range`, or its value when it is a single one (no draw,
    /// so fixed settings leave the random sequence of other draws alone).
    fn draw(&mut self, range: [f64; 2]) -> f64 {
        match range[0] == range[1] {
            true => range[0],
            false => self.random.uniform(range[0], range[1]),
        }
    }

    /// One box: on each leg a lead-in, then pitch, roll and yaw each
    /// followed by a pause (and any `extra` manoeuvres of the leg after
    /// them), then the turn to the next leg (the long way
    /// round for a clover leaf). The turn after the last leg back to the
    /// first heading is flown when `turn_back`.
    fn fly_box(&mut self, scenario: &Scenario, turn_back: bool) {
        let box_ = &scenario.raw.calibration;
        self.wander.1 = box_.heading_wander_deg;
        let start = self.now();
        let headings = &box_.headings_deg;
        for (leg, &heading) in headings.iter().enumerate() {
            let lead_in = self.draw(box_.lead_in_s);
            self.level(lead_in, heading, box_.turbulence_deg, box_.speed_m_s);
            let last = leg + 1 == headings.len();
            let turns = !last || turn_back;
            let flown = leg_plan(box_, heading);
            for (k, &(kind, fraction)) in flown.iter().enumerate() {
                self.manoeuvre(scenario, kind, heading, fraction);
                // The last manoeuvre before a turn is followed by the
                // crew's own lead into it, where one is given.
                let pause = match box_.turn_after_s {
                    Some(range) if turns && k + 1 == flown.len() => self.draw(range),
                    _ => self.draw(box_.pause_s),
                };
                self.level(pause, heading, box_.turbulence_deg, box_.speed_m_s);
            }
            let end = self.now();
            let next = headings[(leg + 1) % headings.len()];
            if last {
                self.path.boxes.push(Stretch {
                    t_start_s: start,
                    t_end_s: end,
                });
            }
            if turns {
                let change = (next - heading + 540.0).rem_euclid(360.0) - 180.0;
                let change = match box_.clover_leaf && change != 0.0 {
                    true => change - 360.0 * change.signum(),
                    false => change,
                };
                let rate = self.draw(box_.turn_rate_deg_s);
                match box_.turn_entry_s[1] > 0.0 {
                    true => {
                        let entry = self.draw(box_.turn_entry_s);
                        self.banked_turn(heading, change, (rate, entry), box_.speed_m_s, box_.turbulence_deg);
                    }
                    false => self.turn_by(heading, change, rate, box_.speed_m_s, box_.turbulence_deg),
                }
            }
        }
        self.wander.1 = 0.0;
    }

    /// Climbs (or descends) straight on `heading_deg` to `to_m` above
    /// ground at 5 m/s, or over 60 s if that is slower. The nose follows
    /// the flight-path angle asin(v_z / v), eased in and out over 4 s as a
    /// pilot pitches up into a climb and levels off.
    fn change_height(&mut self, to_m: f64, heading_deg: f64, speed_m_s: f64, turbulence_deg: f64) {
        let from = self.pose.height_agl_m;
        let seconds = ((from - to_m).abs() / 5.0).max(60.0);
        let samples = self.samples(seconds);
        let path_angle_deg = ((to_m - from) / seconds / speed_m_s)
            .clamp(-1.0, 1.0)
            .asin()
            .to_degrees();
        let ease = self.samples(4.0) as f64;
        for k in 0..samples {
            self.pose.height_agl_m = from + (to_m - from) * (k + 1) as f64 / samples as f64;
            let edge = (k.min(samples - 1 - k) as f64 / ease).min(1.0);
            let pitch = path_angle_deg * (0.5 - 0.5 * (PI * edge).cos());
            self.gust(turbulence_deg);
            self.step(heading_deg, [0.0, pitch, 0.0], speed_m_s);
        }
    }

    /// From the survey (or the start) to the box: a straight climb on the
    /// first leg's heading when `climb_before`, otherwise a climb on a
    /// heading across it and a turn onto the first leg.
    fn climb_to_box(&mut self, scenario: &Scenario) {
        let box_ = &scenario.raw.calibration;
        let first = box_.headings_deg.first().copied().unwrap_or(0.0);
        let heading = self.pose.yaw_deg.rem_euclid(360.0);
        match box_.climb_before {
            true => {
                self.turn(heading, first, 3.0, box_.speed_m_s, 0.3);
                self.change_height(box_.altitude_m, first, box_.speed_m_s, 0.3);
            }
            false => {
                let across = (first + 90.0).rem_euclid(360.0);
                self.turn(heading, across, 3.0, box_.speed_m_s, 0.3);
                self.change_height(box_.altitude_m, across, box_.speed_m_s, 0.3);
                self.turn(across, first, 3.0, box_.speed_m_s, 0.3);
            }
        }
    }

    /// Turns towards the survey area, descends to survey height in a
    /// straight glide, and turns onto the next line's heading.
    fn transit(&mut self, scenario: &Scenario, line_heading_deg: f64) {
        let survey = &scenario.raw.survey;
        let heading = self.pose.yaw_deg.rem_euclid(360.0);
        let bearing = (survey.line_heading_deg + 90.0).rem_euclid(360.0);
        self.turn(heading, bearing, 3.0, survey.speed_m_s, 0.1);
        self.change_height(survey.altitude_m, bearing, survey.speed_m_s, 0.3);
        self.turn(bearing, line_heading_deg, 3.0, survey.speed_m_s, 0.3);
        self.level(20.0, line_heading_deg, survey.turbulence_deg, survey.speed_m_s);
    }

    /// Lines `lines` of the survey in alternating directions, line k on
    /// `base_heading_deg` when k is even and on its reciprocal when odd,
    /// joined by 180° turns whose path is a half circle one line spacing
    /// across, with a standard bank shown.
    fn fly_lines(&mut self, scenario: &Scenario, lines: std::ops::Range<usize>, base_heading_deg: f64) {
        let survey = &scenario.raw.survey;
        let last_block = lines.end == survey.line_count;
        let first_pose = self.path.poses.len();
        for line in lines {
            let heading = (base_heading_deg + 180.0 * (line % 2) as f64).rem_euclid(360.0);
            let number = 1001.0 + line as f64;
            let t_start_s = self.now();
            self.pose.line = number;
            for _ in 0..self.samples(survey.line_length_m / survey.speed_m_s) {
                self.gust(survey.turbulence_deg);
                self.step(heading, [0.0; 3], survey.speed_m_s);
            }
            self.path.lines.push((
                number,
                heading,
                Stretch {
                    t_start_s,
                    t_end_s: self.now() - self.dt_s,
                },
            ));
            self.pose.line = 0.0;
            let turn_speed = PI * survey.line_spacing_m / 2.0 / 60.0;
            let right = if line % 2 == 0 { 180.0 } else { -180.0 };
            let target = heading + right - 1e-9 * right.signum();
            self.turn(heading, target, 3.0, turn_speed, 0.3);
            self.pose.yaw_deg = (heading + 180.0).rem_euclid(360.0);
        }
        if last_block && survey.tie_count > 0 {
            self.fly_ties(scenario, first_pose, base_heading_deg);
        }
    }

    /// The tie lines across the block of lines flown since pose
    /// `first_pose`: `tie_count` of them perpendicular to
    /// `base_heading_deg`, spread evenly along the block and reaching past
    /// its outer lines, flown in alternating directions, each reached by a
    /// turn toward its start, a straight transit and a turn onto it.
    fn fly_ties(&mut self, scenario: &Scenario, first_pose: usize, base_heading_deg: f64) {
        let survey = &scenario.raw.survey;
        let (sin, cos) = base_heading_deg.to_radians().sin_cos();
        // Along and across the lines (across: to the right of the base heading).
        let along = |p: &Pose| p.northing_m * cos + p.easting_m * sin;
        let across = |p: &Pose| -p.northing_m * sin + p.easting_m * cos;
        let on_lines = self.path.poses[first_pose..].iter().filter(|p| p.line != 0.0);
        let (mut a_range, mut c_range) = ([f64::MAX, f64::MIN], [f64::MAX, f64::MIN]);
        for pose in on_lines {
            let (a, c) = (along(pose), across(pose));
            a_range = [a_range[0].min(a), a_range[1].max(a)];
            c_range = [c_range[0].min(c), c_range[1].max(c)];
        }
        if a_range[0] > a_range[1] {
            return;
        }
        let reach = survey.line_spacing_m.max(200.0);
        let count = survey.tie_count;
        for tie in 0..count {
            let a = a_range[0] + (a_range[1] - a_range[0]) * (tie + 1) as f64 / (count + 1) as f64;
            let (from, to, heading) = match tie % 2 {
                0 => (c_range[1] + reach, c_range[0] - reach, base_heading_deg - 90.0),
                _ => (c_range[0] - reach, c_range[1] + reach, base_heading_deg + 90.0),
            };
            let start = (a * cos - from * sin, a * sin + from * cos);
            self.fly_to(survey, start, heading);
            let number = 9001.0 + tie as f64;
            let t_start_s = self.now();
            self.pose.line = number;
            for _ in 0..self.samples((to - from).abs() / survey.speed_m_s) {
                self.gust(survey.turbulence_deg);
                self.step(heading, [0.0; 3], survey.speed_m_s);
            }
            self.path.lines.push((
                number,
                heading.rem_euclid(360.0),
                Stretch {
                    t_start_s,
                    t_end_s: self.now() - self.dt_s,
                },
            ));
            self.pose.line = 0.0;
        }
    }

    /// To `(northing, easting)`, m, arriving on `heading_deg`: a tight turn
    /// toward it, straight and level to it, and a tight turn onto the
    /// heading (the turns are 50 m in radius, so the arrival is within
    /// about that of the point).
    fn fly_to(&mut self, survey: &crate::simulate::scenario::Survey, (north, east): (f64, f64), heading_deg: f64) {
        const RATE_DEG_S: f64 = 3.0;
        let tight = 50.0 * RATE_DEG_S.to_radians();
        let bearing = |pose: &Pose| (east - pose.easting_m).atan2(north - pose.northing_m).to_degrees();
        let now = self.pose.yaw_deg;
        self.turn(now, bearing(&self.pose), RATE_DEG_S, tight, 0.3);
        let track = bearing(&self.pose);
        let distance = (north - self.pose.northing_m).hypot(east - self.pose.easting_m);
        self.level(distance / survey.speed_m_s, track, 0.3, survey.speed_m_s);
        self.turn(track, heading_deg, RATE_DEG_S, tight, 0.3);
        self.pose.yaw_deg = heading_deg.rem_euclid(360.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulate::scenario::RawScenario;

    fn scenario(edit: impl FnOnce(&mut RawScenario)) -> Scenario {
        let mut raw = RawScenario::default();
        edit(&mut raw);
        Scenario::try_from(raw).unwrap()
    }

    #[test]
    fn every_leg_carries_its_manoeuvres_within_the_pilot_ranges() {
        let plan = scenario(|raw| raw.calibration.omit = vec!["yaw@290".into()]);
        let path = fly(&plan, &mut Random::new(3));
        assert_eq!(path.manoeuvres.len(), 11);
        assert!(!path
            .manoeuvres
            .iter()
            .any(|m| m.kind == ManoeuvreKind::Yaw && m.heading_deg == 290.0));
        for m in &path.manoeuvres {
            assert!((2..=4).contains(&m.cycles) && (4.0..8.0).contains(&m.period_s));
            let flown = m.t_end_s - m.t_start_s + path.dt_s;
            assert!((flown - m.cycles as f64 * m.period_s).abs() <= path.dt_s);
        }
        assert_eq!(path.boxes.len(), 1);
    }

    #[test]
    fn tie_lines_cross_every_line_of_the_block_square_on() {
        for (heading, position) in [
            (0.0, BoxPosition::Start),
            (37.0, BoxPosition::Middle),
            (120.0, BoxPosition::End),
        ] {
            let plan = scenario(|raw| {
                raw.survey.line_count = 5;
                raw.survey.tie_count = 3;
                raw.survey.line_heading_deg = heading;
                raw.calibration.position = position;
            });
            let path = fly(&plan, &mut Random::new(8));
            let rows =
                |s: &Stretch| (s.t_start_s / path.dt_s).round() as usize..=(s.t_end_s / path.dt_s).round() as usize;
            let (lines, ties): (Vec<_>, Vec<_>) = path.lines.iter().partition(|(n, _, _)| *n < 9000.0);
            assert_eq!((lines.len(), ties.len()), (5, 3));
            // The lines after the box form the block the ties cross.
            let block: Vec<_> = match position {
                BoxPosition::Middle => lines[2..].to_vec(),
                _ => lines.clone(),
            };
            for (number, tie_heading, tie) in &ties {
                let turn = (tie_heading - heading).rem_euclid(180.0);
                assert!(
                    (turn - 90.0).abs() < 1e-9,
                    "tie {number} on {tie_heading}° against lines on {heading}°"
                );
                let tie_points: Vec<&Pose> = rows(tie).map(|k| &path.poses[k]).collect();
                for (line, _, stretch) in &block {
                    // The tie passes within 40 m of some sample of the line.
                    let closest = rows(stretch)
                        .step_by(5)
                        .flat_map(|k| {
                            let p = &path.poses[k];
                            tie_points
                                .iter()
                                .map(move |q| (p.northing_m - q.northing_m).hypot(p.easting_m - q.easting_m))
                        })
                        .fold(f64::MAX, f64::min);
                    assert!(
                        closest < 40.0,
                        "tie {number} misses line {line} by {closest:.0} m (heading {heading}°)"
                    );
                }
            }
        }
    }

    #[test]
    fn survey_lines_are_parallel_one_spacing_apart() {
        let plan = scenario(|_| {});
        let path = fly(&plan, &mut Random::new(5));
        assert_eq!(path.lines.len(), 4);
        // Mean easting of each northbound/southbound line, m.
        let eastings: Vec<f64> = path
            .lines
            .iter()
            .map(|(_, _, s)| {
                let rows = (s.t_start_s / path.dt_s) as usize..(s.t_end_s / path.dt_s) as usize;
                path.poses[rows.clone()].iter().map(|p| p.easting_m).sum::<f64>() / rows.len() as f64
            })
            .collect();
        for pair in eastings.windows(2) {
            // Turbulent yaw (0.32° rms) drifts the track by a few tens of metres.
            assert!(((pair[1] - pair[0]) - 500.0).abs() < 80.0, "{eastings:?}");
        }
    }
}

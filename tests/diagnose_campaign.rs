//! Physics discovery over many simulated flights: for each effect, ten
//! seeds with drawn parameters (sensor, size, source; fluxgate scale,
//! angle and offset errors), pairs of effects, and clean flights. Every flight carries a tail, a cabin and a wing
//! sensor (the cabin and wing ones with the large aircraft fields whose
//! second-order residual tempts stand-ins). Prints the confusion table
//! (`MAGCOMP_CAMPAIGN_SEEDS=10 cargo test --release --test
//! diagnose_campaign -- --nocapture`).

use std::collections::BTreeMap;

mod common;

use magcomp::diagnose::Diagnosis;
use magcomp::model::{column_level, Extensions, SourceTerm};
use magcomp::simulate::scenario::Scenario;

/// Seeds per effect: 5 in `cargo test` (35 flights; run time:
/// docs/measurements.md, section tests::diagnose_campaign),
/// `MAGCOMP_CAMPAIGN_SEEDS=10` for the full campaign (70 flights, its
/// figures below).
fn seeds() -> u64 {
    std::env::var("MAGCOMP_CAMPAIGN_SEEDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(5)
}

/// Deterministic draws in [0, 1) (SplitMix64).
struct Draw(u64);

impl Draw {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    fn between(&mut self, low: f64, high: f64) -> f64 {
        low + (high - low) * self.next()
    }

    fn pick<'a>(&mut self, items: &[&'a str]) -> &'a str {
        items[((self.next() * items.len() as f64) as usize).min(items.len() - 1)]
    }

    /// A random direction times `size`.
    fn vector(&mut self, size: f64) -> [f64; 3] {
        let z = self.between(-1.0, 1.0);
        let angle = self.between(0.0, std::f64::consts::TAU);
        let r = (1.0 - z * z).sqrt();
        [r * angle.cos() * size, r * angle.sin() * size, z * size]
    }
}

/// A concealed effect and what a correct diagnosis says about it.
#[derive(Debug, Clone)]
enum Truth {
    Lag {
        channel: String,
        lag_s: f64,
    },
    Coupling {
        channel: String,
        source: String,
    },
    Eddy {
        channel: String,
        tau_s: f64,
    },
    Pulsations,
    /// Fluxgate scale factors; the offsets and angles are drawn too.
    Fluxgate {
        scale: [f64; 3],
    },
}

impl Truth {
    fn effect(&self) -> &'static str {
        match self {
            Truth::Lag { .. } => "sensor_lag",
            Truth::Coupling { .. } => "aux_coupling",
            Truth::Eddy { .. } => "eddy_time_constant",
            Truth::Pulsations => "external_field",
            Truth::Fluxgate { .. } => "vector_calibration",
        }
    }

    fn toml(&self, draw: &mut Draw) -> String {
        match self {
            Truth::Lag { channel, lag_s } => {
                format!("[[effect]]\nkind = \"sensor_lag\"\nchannel = \"{channel}\"\nlag_s = {lag_s}\n")
            }
            Truth::Coupling { channel, source } => {
                // nT per unit that the sensor's own residual floor lets show.
                let size = match channel.as_str() {
                    "mag_1_uc" => draw.between(0.15, 0.4),
                    "mag_2_uc" => draw.between(2.0, 4.0),
                    _ => draw.between(1.0, 2.0),
                };
                let k = draw.vector(size);
                format!(
                    "[[effect]]\nkind = \"aux_coupling\"\nchannel = \"{channel}\"\nsource = \"{source}\"\nnt_per_unit = [{}, {}, {}]\n",
                    k[0], k[1], k[2]
                )
            }
            Truth::Eddy { channel, tau_s } => {
                format!("[[effect]]\nkind = \"eddy_time_constant\"\nchannel = \"{channel}\"\ntau_s = {tau_s}\n")
            }
            Truth::Pulsations => format!(
                "[[effect]]\nkind = \"pulsations\"\namplitude_nt = {}\n",
                draw.between(6.0, 10.0)
            ),
            Truth::Fluxgate { scale } => {
                let signed = |draw: &mut Draw, low: f64, high: f64| {
                    draw.between(low, high) * if draw.next() < 0.5 { -1.0 } else { 1.0 }
                };
                let angles: Vec<f64> = (0..3).map(|_| signed(draw, 0.1, 0.8)).collect();
                let offsets: Vec<f64> = (0..3).map(|_| signed(draw, 20.0, 200.0)).collect();
                format!(
                    "[[effect]]\nkind = \"vector_calibration\"\nsensor = \"flux_a\"\nscale = {scale:?}\noffset_nt = {offsets:?}\nnon_orthogonality_deg = {angles:?}\n"
                )
            }
        }
    }

    /// Whether `diagnosis` names this effect with its parameter.
    fn named_in(&self, diagnosis: &Diagnosis) -> bool {
        diagnosis.findings.iter().any(|f| match self {
            Truth::Lag { channel, lag_s } => {
                f.effect.name() == "sensor_lag"
                    && &f.channel == channel
                    && (f.effect.parameters()["lag_s"] - lag_s).abs() < 0.03
            }
            Truth::Coupling { channel, source } => {
                f.effect.name() == "aux_coupling" && &f.channel == channel && f.source.as_ref() == Some(source)
            }
            Truth::Eddy { channel, tau_s } => {
                f.effect.name() == "eddy_time_constant"
                    && &f.channel == channel
                    && (f.effect.parameters()["tau_s"] - tau_s).abs() < 0.2 * tau_s
            }
            Truth::Pulsations => f.effect.name() == "external_field" && f.channel == "mag_1_uc",
            // The aircraft's field at the fluxgate (induced ~2e-3) is
            // calibrated with the sensor's own errors: scale within 4e-3.
            Truth::Fluxgate { scale } => {
                f.effect.name() == "vector_calibration"
                    && f.channel == "flux_a"
                    && ["scale_x", "scale_y", "scale_z"]
                        .iter()
                        .zip(scale)
                        .all(|(k, s)| (f.effect.parameters()[*k] - s).abs() < 4e-3)
            }
        })
    }

    /// The scalar channel the effect is on, when it is on one.
    fn channel(&self) -> Option<&str> {
        match self {
            Truth::Lag { channel, .. } | Truth::Coupling { channel, .. } | Truth::Eddy { channel, .. } => Some(channel),
            Truth::Pulsations | Truth::Fluxgate { .. } => None,
        }
    }

    /// Whether a finding is explained by this effect. (Geomagnetic
    /// variation is in every simulated flight: a daily variation and
    /// 0.3 nT of pulsations by default, recorded by the base station. An
    /// `external_field` finding is therefore never counted as spurious.)
    fn explains(&self, effect: &str, channel: &str) -> bool {
        match self {
            Truth::Lag { channel: c, .. } | Truth::Coupling { channel: c, .. } | Truth::Eddy { channel: c, .. } => {
                effect == self.effect() && channel == c
            }
            Truth::Pulsations => effect == "external_field",
            Truth::Fluxgate { .. } => effect == "vector_calibration" && channel == "flux_a",
        }
    }
}

fn scenario(seed: u64, effects: &str) -> Scenario {
    common::three_sensor_scenario(seed, effects)
}

/// The concealed effect modelled by hand with its true parameters, on
/// the channel it is on (the fluxgate's has none).
fn by_hand(truth: &Truth, log: &magcomp::ingest::flight_log::FlightLog) -> Option<(String, Extensions)> {
    let level = |column: &str| column_level(&log.channel(column).unwrap().values);
    let (channel, model) = match truth {
        Truth::Lag { channel, lag_s } => (
            channel.clone(),
            Extensions {
                lag_s: *lag_s,
                ..Default::default()
            },
        ),
        Truth::Eddy { channel, tau_s } => (
            channel.clone(),
            Extensions {
                eddy_tau_s: *tau_s,
                ..Default::default()
            },
        ),
        Truth::Coupling { channel, source } => (
            channel.clone(),
            Extensions {
                sources: vec![SourceTerm::AuxCoupling {
                    column: source.clone(),
                    level: level(source),
                }],
                ..Default::default()
            },
        ),
        Truth::Pulsations => (
            "mag_1_uc".to_string(),
            Extensions {
                sources: vec![SourceTerm::ExternalField {
                    column: "diurnal".into(),
                    level: level("diurnal"),
                }],
                ..Default::default()
            },
        ),
        Truth::Fluxgate { .. } => return None,
    };
    Some((channel, model))
}

/// One flight of the campaign: its row label and concealed effects.
struct Case {
    row: &'static str,
    seed: u64,
    truths: Vec<Truth>,
}

const SCALARS: [&str; 3] = ["mag_1_uc", "mag_2_uc", "mag_3_uc"];
/// Sources with variation in the fitting band (the fuel pump's slow ripple
/// has almost none).
const SOURCES: [&str; 5] = ["cur_strb", "cur_heat", "cur_com1", "cur_fan", "trim_tab"];

fn cases() -> Vec<Case> {
    let mut cases = Vec::new();
    for k in 0..seeds() {
        let mut draw = Draw(1000 + k);
        // A lag shows only where the aircraft field changes fast: the cabin
        // and wing sensors (the tail sees a few nT).
        let lag = Truth::Lag {
            channel: draw.pick(&SCALARS[1..]).into(),
            lag_s: (draw.between(0.08, 0.3) * 1000.0).round() / 1000.0,
        };
        let coupling = Truth::Coupling {
            channel: draw.pick(&SCALARS).into(),
            source: draw.pick(&SOURCES).into(),
        };
        let eddy = Truth::Eddy {
            channel: draw.pick(&SCALARS[1..]).into(),
            tau_s: (draw.between(0.2, 0.8) * 1000.0).round() / 1000.0,
        };
        let pair_lag = Truth::Lag {
            channel: "mag_2_uc".into(),
            lag_s: (draw.between(0.08, 0.3) * 1000.0).round() / 1000.0,
        };
        let pair_coupling = Truth::Coupling {
            channel: draw.pick(&["mag_1_uc", "mag_3_uc"]).into(),
            source: draw.pick(&SOURCES).into(),
        };
        // Scale errors of 0.5–2 % per axis, either sign.
        let fluxgate = Truth::Fluxgate {
            scale: [0, 1, 2].map(|_| {
                let size = draw.between(0.005, 0.02);
                let sign = if draw.next() < 0.5 { -1.0 } else { 1.0 };
                ((1.0 + sign * size) * 1e4).round() / 1e4
            }),
        };
        let seed = 500 + k;
        cases.push(Case {
            row: "clean",
            seed,
            truths: vec![],
        });
        cases.push(Case {
            row: "sensor_lag",
            seed,
            truths: vec![lag],
        });
        cases.push(Case {
            row: "aux_coupling",
            seed,
            truths: vec![coupling],
        });
        cases.push(Case {
            row: "eddy_time_constant",
            seed,
            truths: vec![eddy],
        });
        cases.push(Case {
            row: "external_field",
            seed,
            truths: vec![Truth::Pulsations],
        });
        cases.push(Case {
            row: "lag + coupling",
            seed,
            truths: vec![pair_lag, pair_coupling],
        });
        cases.push(Case {
            row: "vector_calibration",
            seed,
            truths: vec![fluxgate],
        });
    }
    cases
}

/// Outcome of one flight.
struct Outcome {
    row: &'static str,
    /// Per named effect, the channel's held-out RMS over the truth's.
    against_truth: Vec<f64>,
    /// Every concealed effect named with its parameter.
    named: usize,
    expected: usize,
    /// Findings no concealed effect explains.
    spurious: Vec<String>,
    /// Effects named, for the confusion table ("none" when nothing).
    columns: Vec<String>,
}

#[test]
fn campaign_names_each_effect_and_leaves_clean_flights_alone() {
    use rayon::prelude::*;
    let outcomes: Vec<Outcome> = cases()
        .into_par_iter()
        .map(|case| {
            let mut draw = Draw(7000 + case.seed);
            let effects: String = case.truths.iter().map(|t| t.toml(&mut draw)).collect();
            let log = magcomp::simulate::simulate(&scenario(case.seed, &effects)).unwrap().log;
            let diagnosis = common::diagnose_log(&log);
            // Each named effect against the truth modelled by hand: the
            // diagnosed channel's held-out RMS over the true effect's.
            let against_truth: Vec<f64> = case
                .truths
                .iter()
                .filter(|t| t.named_in(&diagnosis))
                .filter_map(|t| by_hand(t, &log))
                .map(|(channel, model)| {
                    let summary = diagnosis.channels.iter().find(|c| c.channel == channel).unwrap();
                    let model = Extensions {
                        vector_calibration: summary.model.vector_calibration.clone(),
                        ..model
                    };
                    summary.heldout_rms_final_nt / common::heldout_rms(&log, &channel, &model)
                })
                .collect();
            let named = case.truths.iter().filter(|t| t.named_in(&diagnosis)).count();
            let spurious = diagnosis
                .findings
                .iter()
                .filter(|f| {
                    // `unexplained` is right on a channel whose concealed
                    // effect went unnamed, spurious on any other.
                    // The second-order term is the simulator's own
                    // physics (the scalar reads the total field): where it
                    // pays held out it is right on any channel.
                    let concealed_here = case.truths.iter().any(|t| t.channel() == Some(f.channel.as_str()));
                    f.effect.name() != "external_field"
                        && f.effect.name() != "second_order"
                        && !(f.effect.name() == "unexplained" && concealed_here)
                        && !case.truths.iter().any(|t| t.explains(f.effect.name(), &f.channel))
                })
                .map(|f| {
                    format!(
                        "seed {} {}: {} on {} from {:?}",
                        case.seed, case.row, f.effect, f.channel, f.source
                    )
                })
                .collect();
            if named < case.truths.len() {
                let found: Vec<String> = diagnosis
                    .findings
                    .iter()
                    .map(|f| {
                        format!(
                            "{} {} {:?} {:?} {:.4}->{:.4}",
                            f.effect,
                            f.channel,
                            f.source,
                            f.effect.parameters(),
                            f.heldout_rms_before_nt,
                            f.heldout_rms_after_nt
                        )
                    })
                    .collect();
                let rejected: Vec<String> = diagnosis
                    .channels
                    .iter()
                    .map(|c| {
                        format!(
                            "{}: base {:.4} second {:.4} rejected {:?}",
                            c.channel, c.heldout_rms_baseline_nt, c.heldout_rms_second_order_nt, c.strongest_rejected
                        )
                    })
                    .collect();
                println!(
                    "MISS seed {} {}: truth {:?}\n   found {found:#?}\n   {rejected:#?}",
                    case.seed, case.row, case.truths
                );
            }
            let mut columns: Vec<String> = diagnosis.findings.iter().map(|f| f.effect.name().to_string()).collect();
            if columns.is_empty() {
                columns.push("none".into());
            }
            Outcome {
                row: case.row,
                against_truth,
                named,
                expected: case.truths.len(),
                spurious,
                columns,
            }
        })
        .collect();
    // Confusion table: rows are the concealed effects, columns what was named.
    let order = [
        "clean",
        "sensor_lag",
        "aux_coupling",
        "eddy_time_constant",
        "external_field",
        "lag + coupling",
        "vector_calibration",
    ];
    let named_columns = [
        "none",
        "sensor_lag",
        "aux_coupling",
        "eddy_time_constant",
        "external_field",
        "vector_calibration",
        "unexplained",
    ];
    println!("| concealed | flights | named right | {} |", named_columns.join(" | "));
    println!("|---|---|---|{}", "---|".repeat(named_columns.len()));
    let mut totals: BTreeMap<&str, (usize, usize)> = BTreeMap::new();
    for row in order {
        let rows: Vec<&Outcome> = outcomes.iter().filter(|o| o.row == row).collect();
        let right = rows
            .iter()
            .filter(|o| o.named == o.expected && o.spurious.is_empty())
            .count();
        totals.insert(row, (right, rows.len()));
        let counts: Vec<String> = named_columns
            .iter()
            .map(|c| {
                rows.iter()
                    .map(|o| o.columns.iter().filter(|x| x == c).count())
                    .sum::<usize>()
                    .to_string()
            })
            .collect();
        println!("| {row} | {} | {right} | {} |", rows.len(), counts.join(" | "));
        let ratios: Vec<f64> = rows.iter().flat_map(|o| o.against_truth.iter().copied()).collect();
        println!("held-out RMS over the truth's by hand, {row}: {ratios:.3?}");
    }
    let spurious: Vec<&String> = outcomes.iter().flat_map(|o| &o.spurious).collect();
    println!("spurious findings: {spurious:#?}");
    // The goal is every flight right. Measured on this campaign with
    // MAGCOMP_CAMPAIGN_SEEDS=10: clean 10/10, no finding but the base station's
    // (geomagnetic variation is in every simulated flight), and no
    // spurious finding in 70 flights. Before the search started from the
    // λ criterion that predicts the held-out headings better, the trim tab
    // (which follows the slow pitch) stood in for the bias blocked PRESS
    // left on the quiet wing sensor on 13 flights, two of them clean.
    // Misses: couplings of the strobe's 80 ms pulses or the slow trim tab
    // on the tail sensor, a few hundredths of a nT in the fitting band;
    // pulsations that lower the tail's held-out RMS by 16–23 %, short of
    // 30 %. The eddy lag is discretised for inputs linear between samples,
    // so its delay is τ: the half-sample recursion it replaced put every τ
    // ~0.05 s long (0.4–0.6 s on the wing 23 % high) and named a 0.08 s
    // wing lag as an eddy τ on seed 509. The leading candidates are also
    // scored under the other λ criterion: under blocked PRESS alone a wing
    // eddy τ lost to a lag on one flight, and a wing τ of 0.613 s (seed 501)
    // came out at 0.46 s. Fluxgate errors (0.5–2 % scale, 0.1–0.8°,
    // 20–200 nT) are named on all ten flights with every scale factor
    // within 4e-3, and never on another flight. These floors keep what
    // works from regressing. With five seeds (seeds 500–504, the default)
    // the same flights give: clean 5, lag 5, coupling 4, eddy 5,
    // pulsations 3, the pair 3, fluxgate 5.
    let floors = match seeds() {
        10 => [
            ("clean", 10),
            ("sensor_lag", 10),
            ("aux_coupling", 7),
            ("eddy_time_constant", 10),
            ("external_field", 8),
            ("lag + coupling", 6),
            ("vector_calibration", 10),
        ],
        5 => [
            ("clean", 5),
            ("sensor_lag", 5),
            ("aux_coupling", 4),
            ("eddy_time_constant", 5),
            ("external_field", 3),
            ("lag + coupling", 3),
            ("vector_calibration", 5),
        ],
        other => panic!("MAGCOMP_CAMPAIGN_SEEDS={other}: floors are measured for 5 and 10 seeds"),
    };
    // Named effects hold out about as well as the truth modelled by hand:
    // the channel's held-out RMS (with every finding, λ as the pipeline
    // picks it) over that of the concealed effect with its true
    // parameters. Measured over the 51 effects named in the ten-seed
    // campaign: 0.53–1.14, below 1 where the diagnosis also named the
    // base station on the same channel or its fitted parameter suits the
    // held-out headings better; above 1 by the parameters' errors within
    // their tolerances (lag ±0.03 s, τ ±20 %). The bound is 1.2.
    let worst = outcomes
        .iter()
        .flat_map(|o| o.against_truth.iter().map(move |r| (r, o.row)))
        .fold((0.0f64, ""), |(w, row), (r, o)| if *r > w { (*r, o) } else { (w, row) });
    assert!(worst.0 <= 1.2, "{}: held out {:.2} times the truth's", worst.1, worst.0);
    for (row, floor) in floors {
        let (right, all) = totals[row];
        assert!(
            right >= floor,
            "{row}: {right} of {all} right, fewer than {floor}: {spurious:#?}"
        );
    }
}

/// A flight with a current no column records: a tail scalar, two cabin
/// scalars and a cabin fluxgate, the current's dipole placed among them
/// (0.5–1 m from the scalars' middle, any direction, a moment giving 1–5
/// nT at the nearest cabin scalar; the fluxgate 0.4–0.8 m from it),
/// switched on and off, alone or with ramps and slow cycles, and a
/// survey of 8 lines and 2 ties flown 100–200 m over 12 dipoles so that
/// the sensors' separation carries a real gradient. Drawn by this file's own
/// generator, not the simulator's. Returns the scenario and the field
/// the current gives each cabin scalar per ampere (nT).
fn unrecorded_current_scenario(seed: u64) -> (Scenario, Vec<(String, f64)>) {
    unrecorded_current_scenario_with(seed, 1.0)
}

/// [`unrecorded_current_scenario`] with the current's amplitude `amplitude_a`
/// (0: the same flight, layout and noise without it).
fn unrecorded_current_scenario_with(seed: u64, amplitude_a: f64) -> (Scenario, Vec<(String, f64)>) {
    let mut draw = Draw(0xC0FF_EE00 ^ seed);
    let cabin = [
        [1.5 + draw.between(-0.3, 0.3), 0.3 + draw.between(-0.3, 0.3), 0.2],
        [2.3 + draw.between(-0.3, 0.3), -0.4 + draw.between(-0.3, 0.3), 0.1],
    ];
    let middle: Vec<f64> = (0..3).map(|i| (cabin[0][i] + cabin[1][i]) / 2.0).collect();
    let away_m = draw.between(0.5, 1.0);
    let offset = draw.vector(away_m);
    let source: Vec<f64> = (0..3).map(|i| middle[i] + offset[i]).collect();
    // The cabin fluxgate 0.4–0.8 m from the source.
    let near_m = draw.between(0.4, 0.8);
    let near = draw.vector(near_m);
    let fluxgate = [source[0] + near[0], source[1] + near[1], source[2] + near[2]];
    let distance = |p: &[f64; 3]| (0..3).map(|i| (p[i] - source[i]).powi(2)).sum::<f64>().sqrt();
    let nearest = distance(&cabin[0]).min(distance(&cabin[1]));
    // |B| ≈ 100 m / r³ nT for a moment m in A·m² (μ0/4π = 100 nT·m/A).
    let at_nearest_nt = draw.between(1.0, 5.0);
    let moment = draw.vector(at_nearest_nt * nearest.powi(3) / 100.0);
    // Switched loads: their edges reach the calibration band, where the
    // box can see them (a current that only ramps or cycles over tens of
    // seconds stays below the band's 0.1 Hz and is seen on the survey
    // alone).
    let waveform = draw.pick(&["steps", "mixed"]);
    let text = format!(
        r#"
        seed = {}
        [survey]
        line_count = 8
        line_length_m = 5000.0
        tie_count = 2
        altitude_m = {}
        line_heading_deg = {}
        [crust]
        dipole_count = 12
        [[scalar]]
        name = "mag_1_uc"
        location = "tail"
        position_m = [-9.0, 0.0, -0.5]
        [[scalar]]
        name = "mag_2_uc"
        location = "cabin"
        position_m = {:?}
        [[scalar]]
        name = "mag_3_uc"
        location = "cabin"
        position_m = {:?}
        [[fluxgate]]
        name = "flux_a"
        position_m = {:?}
        [[effect]]
        kind = "unrecorded_current"
        position_m = {:?}
        moment_a_m2_per_a = {:?}
        amplitude_a = {amplitude_a:?}
        waveform = "{waveform}"
        "#,
        31_000 + seed,
        draw.between(100.0, 200.0),
        draw.between(0.0, 180.0),
        cabin[0],
        cabin[1],
        fluxgate,
        source,
        moment
    );
    let raw: magcomp::simulate::scenario::RawScenario = toml::from_str(&text).unwrap();
    let per_ampere = ["mag_2_uc", "mag_3_uc"]
        .iter()
        .zip(cabin)
        .map(|(name, p)| {
            let r: Vec<f64> = (0..3).map(|i| p[i] - source[i]).collect();
            let field = magcomp::simulate::physics::dipole_field_nt(moment, [r[0], r[1], r[2]]);
            (name.to_string(), field.iter().map(|v| v * v).sum::<f64>().sqrt())
        })
        .collect();
    (Scenario::try_from(raw).unwrap(), per_ampere)
}

/// The unrecorded current is found from the other sensors alone, and the
/// survey against truth improves with the geology's amplitude held: over
/// random layouts, by default (`[diagnose] cross_sensor =
/// "survey_fitted"`: a signal whose gain the survey lines fit, each held
/// out) and under `"survey"` (with box-fitted signals the survey bears
/// out), every applied `cross_sensor` finding leaves its channel's survey
/// lines no further from truth than plain Tolles-Lawson (10 % + 0.01 nT),
/// every channel's anomaly gain stays within the tolerance, a cabin
/// scalar the current reaches (2 nT/A or more, or the most) gets one by
/// default on at least [`LEAST_FOUND`] flights of ten, and on each
/// flight's clean twin (the same layout and noise without the current)
/// none is applied under either setting. Where a survey-fitted term is
/// applied, an anomaly injected on a survey line comes out at the stated
/// gain (within 0.002 at its peak), and the saved model applied to the
/// flight gives the same compensation.
///
/// Measured on seeds 0–9, by default: found on 2 (seed 3 1.73 → 0.55 nT
/// and seed 4 1.54 → 0.57 nT against truth on the survey lines, gains
/// −2.23 and −0.61, anomaly gains 0.991 and 0.998, the injected anomaly
/// within 0.0001 of the stated gain). Three more were fitted and held
/// back: seed 0's (gain −3.32) would scale an anomaly by 0.976, and on
/// seeds 6 and 7 the lines' levels at the crossovers spread wider with it
/// (0.43 against 0.34 nT, 0.50 against 0.31 nT), though the survey came
/// nearer the truth. Under `"survey"` the box-fitted signals add seed 0
/// (1.07 → 0.86 nT) and seed 7's mag_3_uc (0.59 → 0.45 nT), and seed 4
/// goes to 0.29 nT. None is applied on a clean twin. On seeds 2 and 8 the
/// current reaches both cabin scalars alike (7.0–7.3 and 5.2 nT/A): the
/// fluxgate less the other cabin scalar then holds little of it.
#[test]
fn an_unrecorded_current_is_found_from_the_other_sensors() {
    use rayon::prelude::*;
    let n = seeds().max(5) * 2;
    let outcomes: Vec<(bool, Vec<String>)> = (0..n).into_par_iter().map(unrecorded_current_flight).collect();
    let found = outcomes.iter().filter(|(f, _)| *f).count();
    let failures: Vec<String> = outcomes.into_iter().flat_map(|(_, f)| f).collect();
    println!("cross_sensor applied by default to a channel the current reaches on {found} of {n} flights");
    assert!(failures.is_empty(), "{failures:#?}");
    assert!(
        found * 10 >= n as usize * LEAST_FOUND,
        "found on {found} of {n} flights"
    );
}

/// One flight of [`an_unrecorded_current_is_found_from_the_other_sensors`]:
/// whether the default applied a `cross_sensor` finding to a channel the
/// current reaches, and what failed.
fn unrecorded_current_flight(seed: u64) -> (bool, Vec<String>) {
    use magcomp::config::{FlightJob, Settings};
    let (scenario, per_ampere) = unrecorded_current_scenario(seed);
    let flight = magcomp::simulate::simulate(&scenario).unwrap();
    let folder = tempfile::tempdir().unwrap();
    let csv = folder.path().join("flight.csv");
    magcomp::formats::write_flight_log(&flight.log, &csv).unwrap();
    let job = FlightJob::new(&csv);
    let mut default = Settings::default();
    default.vector.enabled = false;
    let mut survey = default.clone();
    survey.diagnose.cross_sensor = magcomp::diagnose::CrossSensorUse::Survey;
    let out = folder.path().join("out.csv");
    let auto = magcomp::pipeline::run(&job, &default, &out).unwrap();
    let surveyed = magcomp::pipeline::run(&job, &survey, &out).unwrap();
    let plain = magcomp::pipeline::run(&job, &common::plain(), &out).unwrap();
    // `MAGCOMP_CROSS_KEEP=DIR` leaves each flight there to look at with
    // `magcomp diagnose`.
    if let Ok(keep) = std::env::var("MAGCOMP_CROSS_KEEP") {
        std::fs::copy(&csv, std::path::Path::new(&keep).join(format!("unrecorded_{seed}.csv"))).unwrap();
    }
    for finding in auto.result.diagnosis.iter().flat_map(|d| d.findings.iter()) {
        println!(
            "seed {seed}: finding {} {} {:?} {:?}: held out {:.4} → {:.4} nT; {:?}",
            finding.channel,
            finding.effect,
            finding.source,
            finding.effect.parameters().get("survey_gain"),
            finding.heldout_rms_before_nt,
            finding.heldout_rms_after_nt,
            finding.not_applied
        );
    }
    // The same layout and noise without the current: nothing for the
    // other sensors to see, and nothing applied.
    let (twin, _) = unrecorded_current_scenario_with(seed, 0.0);
    let twin = magcomp::simulate::simulate(&twin).unwrap();
    let twin_csv = folder.path().join("twin.csv");
    magcomp::formats::write_flight_log(&twin.log, &twin_csv).unwrap();
    let mut failures = Vec::new();
    for (name, settings) in [("by default", &default), ("under \"survey\"", &survey)] {
        let clean = magcomp::pipeline::run(&FlightJob::new(&twin_csv), settings, &out).unwrap();
        failures.extend(
            (clean.result.applied_findings.iter())
                .filter(|f| f.effect.name() == "cross_sensor")
                .map(|f| {
                    format!(
                        "seed {seed}, without the current: cross_sensor applied to {} {name}",
                        f.channel
                    )
                }),
        );
    }
    let strongest = per_ampere.iter().max_by(|a, b| a.1.total_cmp(&b.1)).unwrap().0.clone();
    let line = &flight.log.channel("line").unwrap().values;
    let mut found = false;
    for (run, name) in [(&auto, "default"), (&surveyed, "\"survey\"")] {
        for (k, quality) in run.result.channels.iter().enumerate() {
            let channel = &quality.channel;
            let truth = flight.truth.earth_total_nt(channel).unwrap();
            let error = |run: &magcomp::pipeline::FlightRun| {
                magcomp::simulate::truth::survey_line_error_nt(&run.compensation.channels[k].values, truth, line)
            };
            let (plain_nt, run_nt) = (error(&plain), error(run));
            let cross: Vec<&magcomp::pipeline::AppliedFinding> = (run.result.applied_findings.iter())
                .filter(|f| f.channel == *channel && f.effect.name() == "cross_sensor")
                .collect();
            let gain = quality.anomaly_gain.unwrap_or(f64::NAN);
            println!(
                "seed {seed} {name} {channel} ({:.1} nT/A): survey against truth plain {plain_nt:.3} → {run_nt:.3} nT; cross_sensor {:?}; anomaly gain {gain:.4}; {}",
                per_ampere.iter().find(|(c, _)| c == channel).map_or(0.0, |p| p.1),
                cross.iter().map(|f| f.source.clone().unwrap_or_default()).collect::<Vec<_>>(),
                quality.verdict
            );
            let reached = per_ampere.iter().any(|(c, nt)| c == channel && *nt >= REACHED_NT_PER_A);
            if name == "default" && (reached || *channel == strongest) && !cross.is_empty() {
                found = true;
            }
            if !cross.is_empty() && run_nt > 1.1 * plain_nt + 0.01 {
                failures.push(format!(
                    "seed {seed} {name} {channel}: cross_sensor harmed the survey, {plain_nt} → {run_nt}"
                ));
            }
            if (gain - 1.0).abs() > magcomp::model::ANOMALY_GAIN_TOLERANCE {
                failures.push(format!("seed {seed} {name} {channel}: anomaly gain {gain}"));
            }
        }
    }
    failures.extend(survey_fitted_checks(seed, &auto, (&flight.log, folder.path())));
    (found, failures)
}

/// For each channel of `run` whose model has a survey-fitted cross-sensor
/// term: the stated anomaly gain against an anomaly injected at the middle
/// of a survey line of `log` (within 0.002 at its peak), and the model
/// saved and applied to the same flight (the same compensation within
/// 1e-9 nT). What failed.
fn survey_fitted_checks(
    seed: u64,
    run: &magcomp::pipeline::FlightRun,
    (log, folder): (&magcomp::ingest::flight_log::FlightLog, &std::path::Path),
) -> Vec<String> {
    let mut failures = Vec::new();
    let fitted =
        |m: &&magcomp::model::FittedModel| (m.spec.extensions.sources.iter()).any(|s| s.survey_gain().is_some());
    if !run.result.models.iter().any(|m| fitted(&m)) {
        return failures;
    }
    let lines = log.survey_lines();
    let (_, rows) = &lines[(seed as usize) % lines.len()];
    let centre_row = rows[rows.len() / 2];
    let (injected, delta) = common::with_anomaly(log, (centre_row, 60.0, 8.0));
    let peak: Vec<usize> = (rows.iter().copied())
        .filter(|&r| (log.time_s()[r] - log.time_s()[centre_row]).abs() < 2.0)
        .collect();
    for model in run.result.models.iter().filter(fitted) {
        let stated = model.anomaly_gain_at(log, &[], &peak).unwrap();
        let clean = model.predict(log).unwrap().interference_nt;
        let with = model.predict(&injected).unwrap().interference_nt;
        let worst = (peak.iter().zip(&stated))
            .map(|(&r, s)| (s - (1.0 - (with[r] - clean[r]) / delta[r])).abs())
            .fold(0.0, f64::max);
        println!(
            "seed {seed} {}: survey-fitted term, stated gain {:.4}, injected off by {worst:.5}",
            model.channel, stated[0]
        );
        if worst > 0.002 {
            failures.push(format!(
                "seed {seed} {}: stated gain off the injected by {worst}",
                model.channel
            ));
        }
    }
    let settings = {
        let mut s = magcomp::config::Settings::default();
        s.vector.enabled = false;
        s
    };
    let model_json = folder.join("model.json");
    let outputs = magcomp::output::sink::FlightOutputs {
        compensated: folder.join("saved.csv"),
        model_json: Some(model_json.clone()),
        quality_json: None,
        report_html: None,
        diagnosis_json: None,
    };
    magcomp::output::sink::write(run, &settings, &outputs).unwrap();
    let mut job = magcomp::config::FlightJob::new(folder.join("flight.csv"));
    job.model = Some(model_json);
    let applied = magcomp::pipeline::run(&job, &settings, &folder.join("applied.csv")).unwrap();
    for (ours, theirs) in run.compensation.channels.iter().zip(&applied.compensation.channels) {
        let worst = (ours.values.iter().zip(&theirs.values))
            .filter(|(a, b)| a.is_finite() || b.is_finite())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        if worst.is_nan() || worst > 1e-9 {
            failures.push(format!(
                "seed {seed}: the saved model applied gives {} off by {worst} nT",
                ours.channel
            ));
        }
    }
    failures
}

/// Flights of ten on which a channel the current reaches must get an
/// applied `cross_sensor` by default (see the test).
const LEAST_FOUND: usize = 2;

/// A channel the current reaches by this much, nT per A, or the one it
/// reaches most, counts as found.
const REACHED_NT_PER_A: f64 = 2.0;

//! Physics discovery on the simulator's concealed-effect sample flights:
//! the right effect named with its parameter, the held-out fit improved,
//! and a clean flight left alone.

use std::path::PathBuf;

use magcomp::config::{FlightJob, Pipeline};
use magcomp::diagnose::Diagnosis;
use magcomp::formats::read_flight_log;
use magcomp::pipeline::diagnose_flight;

fn diagnose(name: &str) -> Diagnosis {
    let input = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("sample_flights")
        .join(name);
    let pipeline = Pipeline::default();
    let log = read_flight_log(&input, &pipeline.settings.ingest).unwrap();
    let job = FlightJob::new(input);
    diagnose_flight(&log, &job, &pipeline.settings, &pipeline.settings.diagnose).unwrap()
}

#[test]
fn a_clean_flight_gives_no_finding() {
    let diagnosis = diagnose("clean.csv");
    assert!(diagnosis.findings.is_empty(), "{:#?}", diagnosis.findings);
    for channel in &diagnosis.channels {
        assert_eq!(channel.heldout_rms_final_nt, channel.heldout_rms_baseline_nt);
        // The search started from whichever λ criterion predicted the
        // held-out headings better (measured: PRESS for the tail, 0.0108 →
        // 0.0098 nT; blocked PRESS for the cabin, 0.0254 against 0.0353).
        let other = channel.heldout_rms_other_criterion_nt.unwrap();
        let started_with_other = channel.search_criterion != magcomp::numerics::solve::Criterion::BlockedPress;
        assert_eq!(
            started_with_other,
            other < channel.heldout_rms_baseline_nt,
            "{channel:?}"
        );
    }
}

#[test]
fn a_concealed_lag_is_named_with_its_lag() {
    // concealed_a: mag_2_uc reads 0.15 s late.
    let diagnosis = diagnose("concealed_a.csv");
    assert_eq!(diagnosis.findings.len(), 1, "{:#?}", diagnosis.findings);
    let finding = &diagnosis.findings[0];
    assert_eq!(
        (finding.effect.name(), finding.channel.as_str()),
        ("sensor_lag", "mag_2_uc")
    );
    let lag = finding.effect.parameters()["lag_s"];
    assert!((lag - 0.15).abs() < 0.03, "lag {lag}");
    // Modelling the lag takes the held-out RMS to the clean flight's level
    // for this sensor (0.025 nT), from 0.55 nT.
    assert!(
        finding.heldout_rms_before_nt > 10.0 * finding.heldout_rms_after_nt,
        "{finding:?}"
    );
    assert!(finding.heldout_rms_after_nt < 0.04);
    assert!(!finding.located.is_empty());
}

#[test]
fn concealed_couplings_are_traced_to_their_sources() {
    // concealed_b: the radio current reaches the tail sensor, the trim tab
    // the cabin sensor.
    let diagnosis = diagnose("concealed_b.csv");
    let found: Vec<(&str, &str, Option<&str>)> = diagnosis
        .findings
        .iter()
        .map(|f| (f.effect.name(), f.channel.as_str(), f.source.as_deref()))
        .collect();
    assert_eq!(
        found,
        vec![
            ("aux_coupling", "mag_1_uc", Some("cur_com1")),
            ("aux_coupling", "mag_2_uc", Some("trim_tab")),
        ]
    );
    // The coupling vector of the radio current: (0.12, −0.08, 0.20) nT/A.
    let tail = diagnosis.findings[0].effect.parameters();
    for (axis, truth) in ["k_x_nt_per_unit", "k_y_nt_per_unit", "k_z_nt_per_unit"]
        .iter()
        .zip([0.12, -0.08, 0.2])
    {
        assert!((tail[*axis] - truth).abs() < 0.03, "{axis}: {} vs {truth}", tail[*axis]);
    }
    // Each finding removes most of what its channel's search started from.
    // Measured: tail 0.113 → 0.012 nT; cabin 0.140 → 0.040 nT, its search
    // starting from λ by PRESS, which already took plain Tolles-Lawson from
    // 0.323 nT to 0.140 nT (what remains is mostly the total field's
    // second-order term).
    for (finding, share) in diagnosis.findings.iter().zip([0.2, 0.35]) {
        assert!(
            finding.heldout_rms_after_nt < share * finding.heldout_rms_before_nt,
            "{finding:?}"
        );
    }
    // And each channel's diagnosed model (λ by blocked PRESS) against plain
    // Tolles-Lawson. Measured: tail 0.113 → 0.022 nT, cabin 0.323 → 0.040 nT.
    for (channel, share) in diagnosis.channels.iter().zip([0.25, 0.15]) {
        assert!(
            channel.heldout_rms_final_nt < share * channel.heldout_rms_baseline_nt,
            "{channel:?}"
        );
    }
}

#[test]
fn strong_pulsations_are_traced_to_the_base_station() {
    // concealed_d: 6 nT of pulsations, recorded by the base station.
    let diagnosis = diagnose("concealed_d.csv");
    let tail = diagnosis.findings.iter().find(|f| f.channel == "mag_1_uc").unwrap();
    assert_eq!(
        (tail.effect.name(), tail.source.as_deref()),
        ("external_field", Some("diurnal"))
    );
    // The sensor sees the variation one to one.
    assert!(
        (tail.effect.parameters()["gain"] - 1.0).abs() < 0.1,
        "{:?}",
        tail.effect.parameters()
    );
    assert!(tail.heldout_rms_after_nt < 0.5 * tail.heldout_rms_before_nt);
}

#[test]
fn an_eddy_time_constant_is_told_apart_from_a_lag() {
    // concealed_c: mag_2_uc's eddy currents lag by τ = 0.4 s (and the
    // fluxgate carries calibration errors, tested below). A scalar lag would delay everything the sensor sees; the
    // held-out fit prefers the lagged eddy terms.
    let diagnosis = diagnose("concealed_c.csv");
    let cabin: Vec<&magcomp::diagnose::Finding> =
        diagnosis.findings.iter().filter(|f| f.channel == "mag_2_uc").collect();
    assert_eq!(cabin[0].effect.name(), "eddy_time_constant", "{cabin:#?}");
    let tau = cabin[0].effect.parameters()["tau_s"];
    assert!((tau - 0.4).abs() < 0.08, "τ {tau}");
    assert!(cabin[0].heldout_rms_after_nt < 0.3 * cabin[0].heldout_rms_before_nt);
    // And the lag flight is still a lag, not an eddy time constant.
    assert_eq!(diagnose("concealed_a.csv").findings[0].effect.name(), "sensor_lag");
}

/// The lower-triangular correction C (CᵀC = (M Mᵀ)⁻¹) and offset q of a
/// fluxgate that reads m = M b + q.
fn effective_correction(m: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    // M⁻¹ by cofactors, then A = M⁻ᵀ M⁻¹.
    let cofactor = |i: usize, j: usize| {
        let (r0, r1) = ((i + 1) % 3, (i + 2) % 3);
        let (c0, c1) = ((j + 1) % 3, (j + 2) % 3);
        m[r0][c0] * m[r1][c1] - m[r0][c1] * m[r1][c0]
    };
    let det: f64 = (0..3).map(|j| m[0][j] * cofactor(0, j)).sum();
    let inverse = [0, 1, 2].map(|i| [0, 1, 2].map(|j| cofactor(j, i) / det));
    let a = |i: usize, j: usize| (0..3).map(|l| inverse[l][i] * inverse[l][j]).sum::<f64>();
    // Reverse the axes, Cholesky, reverse back: C = P Lᵀ P.
    let reversed = faer::Mat::from_fn(3, 3, |i, j| a(2 - i, 2 - j));
    let lower = magcomp::numerics::linalg::cholesky_lower(reversed.as_ref()).unwrap();
    [0, 1, 2].map(|i| [0, 1, 2].map(|j| lower[(2 - j, 2 - i)]))
}

#[test]
fn fluxgate_calibration_errors_are_named_with_their_parameters() {
    // concealed_c: flux_a has scale factors (1.015, 0.985, 1.01),
    // non-orthogonality (0.6, −0.4, 0.8)° and offsets (120, −80, 45) nT.
    // The aircraft's own field at the fluxgate (permanent p, induced D in
    // the truth file) is indistinguishable from them: the fluxgate reads
    // m = K(I + D) b + K p + o, and the calibration must recover that.
    let diagnosis = diagnose("concealed_c.csv");
    let found: Vec<&magcomp::diagnose::Finding> = diagnosis
        .findings
        .iter()
        .filter(|f| f.effect.name() == "vector_calibration")
        .collect();
    assert_eq!(found.len(), 1, "{:#?}", diagnosis.findings);
    assert_eq!(
        (found[0].channel.as_str(), found[0].source.as_deref()),
        ("flux_a", Some("mag_1_uc"))
    );
    let check = diagnosis.fluxgate.as_ref().unwrap();
    let truth: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("sample_flights/concealed_c.truth.json"),
        )
        .unwrap(),
    )
    .unwrap();
    let fluxgate = &truth["fluxgates"][0];
    let vector = |v: &serde_json::Value| [0, 1, 2].map(|i| v[i].as_f64().unwrap());
    let calibration = &fluxgate["calibration"];
    let k = magcomp::simulate::physics::FluxgateErrors::new(
        vector(&calibration["scale"]),
        vector(&calibration["non_orthogonality_deg"]),
        vector(&calibration["offset_nt"]),
    );
    let induced = [0, 1, 2].map(|i| vector(&fluxgate["aircraft"]["induced"][i]));
    let permanent = vector(&fluxgate["aircraft"]["permanent_nt"]);
    let m = [0, 1, 2].map(|i| {
        [0, 1, 2].map(|j| {
            (0..3)
                .map(|l| k.matrix[i][l] * (if l == j { 1.0 } else { 0.0 } + induced[l][j]))
                .sum()
        })
    });
    let expected = effective_correction(m);
    let offset: Vec<f64> = (0..3)
        .map(|i| (0..3).map(|l| k.matrix[i][l] * permanent[l]).sum::<f64>() + k.offset_nt[i])
        .collect();
    let fitted = &check.calibration;
    // The reference (the tail sensor) carries a few nT of its own
    // interference; its mean acts as a common scale error (measured 1.2e-4,
    // 6 nT of the 51 000 nT field). Tolerances: C to 3e-4 (15 nT), offsets
    // to 15 nT (measured 1.6, 2.3 and 9.7 nT: the z offset trades against
    // the z scale, because the z axis stays near vertical).
    #[allow(clippy::needless_range_loop)]
    for i in 0..3 {
        for j in 0..=i {
            assert!(
                (fitted.correction[i][j] - expected[i][j]).abs() < 3e-4,
                "C[{i}][{j}] {} against {}",
                fitted.correction[i][j],
                expected[i][j]
            );
        }
        assert!(
            (fitted.offset_nt[i] - offset[i]).abs() < 15.0,
            "offset {i}: {} against {}",
            fitted.offset_nt[i],
            offset[i]
        );
    }
    // Held out, the mismatch of |B| falls from hundreds of nT to the
    // reference sensor's own level.
    assert!(check.heldout_mismatch_before_nt > 300.0, "{check:?}");
    assert!(check.heldout_mismatch_after_nt < 1.0, "{check:?}");
    assert_eq!(found[0].located.len(), 3);
}

#[test]
fn a_clean_fluxgate_is_not_reported() {
    // clean: the residual factory errors (0.05 %, 0.03°, 5 nT) and the
    // aircraft field at the fluxgate leave a mismatch well under the
    // 200 nT threshold.
    let diagnosis = diagnose("clean.csv");
    let check = diagnosis.fluxgate.as_ref().unwrap();
    assert!(check.heldout_mismatch_before_nt < 100.0, "{check:?}");
    assert!(check.heldout_mismatch_after_nt < 1.0, "{check:?}");
    assert!(diagnosis
        .channels
        .iter()
        .all(|c| c.fluxgate == magcomp::diagnose::FluxgateReading::Raw));
}

#[test]
fn an_effect_outside_the_library_is_reported_as_unexplained_where_it_happens() {
    // concealed_b with its radio-current column removed: the radio's field
    // still reaches the tail sensor, but nothing recorded can explain it.
    let input = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("sample_flights/concealed_b.csv");
    let pipeline = Pipeline::default();
    let full = read_flight_log(&input, &pipeline.settings.ingest).unwrap();
    let radio = full.channel("cur_com1").unwrap().values.clone();
    let channels = full
        .channels()
        .iter()
        .filter(|c| c.name != "cur_com1")
        .cloned()
        .collect();
    let log = magcomp::ingest::flight_log::FlightLog::new(
        full.source(),
        full.time_column(),
        full.time_s().to_vec(),
        channels,
    )
    .unwrap();
    let job = FlightJob::new(input);
    let diagnosis = diagnose_flight(&log, &job, &pipeline.settings, &pipeline.settings.diagnose).unwrap();
    let tail: Vec<&magcomp::diagnose::Finding> =
        diagnosis.findings.iter().filter(|f| f.channel == "mag_1_uc").collect();
    assert_eq!(tail.len(), 1, "{tail:#?}");
    assert_eq!(tail[0].effect.name(), "unexplained");
    assert!(tail[0].located.len() >= 2, "{tail:#?}");
    // Every located stretch holds a radio transmission switching on or off
    // (within the filter's reach, 2 s either side).
    let time = log.time_s();
    for stretch in &tail[0].located {
        let switches = (1..radio.len()).any(|i| {
            (radio[i] - radio[i - 1]).abs() > 1.0 && time[i] >= stretch.t_start - 2.0 && time[i] <= stretch.t_end + 2.0
        });
        assert!(switches, "no radio switching near {stretch:?}");
    }
    // The default run says so, with the finding's figures and where.
    let folder = tempfile::tempdir().unwrap();
    let without = folder.path().join("without_radio.csv");
    magcomp::formats::write_flight_log(&log, &without).unwrap();
    let run = magcomp::pipeline::run(
        &FlightJob::new(&without),
        &pipeline.settings,
        &folder.path().join("out.csv"),
    )
    .unwrap();
    let said: Vec<&magcomp::messages::Warning> = (run.result.warnings.iter())
        .filter(|w| matches!(w, magcomp::messages::Warning::Unexplained { .. }))
        .collect();
    assert_eq!(
        said,
        [&magcomp::messages::Warning::Unexplained {
            channel: "mag_1_uc".into(),
            heldout_rms_nt: tail[0].heldout_rms_after_nt,
            residual_to_noise: match &tail[0].effect {
                magcomp::diagnose::Effect::Unexplained(u) => u.residual_to_noise,
                other => panic!("{other:?}"),
            },
            largest_on: tail[0].located.iter().map(|l| l.label.clone()).collect(),
        }],
        "{:#?}",
        run.result.warnings
    );
    // The clean flight and the flight with the column keep no such finding.
    assert!(diagnose("clean.csv")
        .findings
        .iter()
        .all(|f| f.effect.name() != "unexplained"));
}

#[test]
fn a_diagnosis_does_not_depend_on_the_thread_count() {
    // Candidates and channels are scored in parallel; every choice is made
    // from the scores in a fixed order, so one thread and three give the
    // same DIAGNOSIS.json to the byte (concealed_c: an eddy τ and a
    // fluxgate calibration, the most candidates of any sample flight).
    let in_pool = |threads| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        serde_json::to_string(&pool.install(|| diagnose("concealed_c.csv"))).unwrap()
    };
    let single = in_pool(1);
    assert!(single.contains("eddy_time_constant"), "{single}");
    assert_eq!(single, in_pool(3));
}

/// The channel's held-out RMS with plain Tolles-Lawson, with the diagnosed
/// model (as compensation uses it) and with the concealed effect modelled
/// by hand with its true parameters, scored the same way, on `name`'s
/// detected box.
fn diagnosed_and_by_hand(
    name: &str,
    channel: &str,
    truth: impl Fn(&magcomp::ingest::flight_log::FlightLog) -> magcomp::model::Extensions,
) -> [f64; 3] {
    use magcomp::pipeline::choose_vector_sensor;
    let diagnosis = diagnose(name);
    let pipeline = Pipeline::default();
    let options = pipeline.settings.clone();
    let input = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("sample_flights")
        .join(name);
    let log = read_flight_log(&input, &pipeline.settings.ingest).unwrap();
    let windows = magcomp::calibration::detect::detect_manoeuvres(&log, &options.detect)
        .unwrap()
        .calibration_windows(options.detect.window_margin_s);
    let sensor = choose_vector_sensor(&log, None).unwrap();
    let summary = diagnosis.channels.iter().find(|c| c.channel == channel).unwrap();
    let hand = magcomp::model::Extensions {
        vector_calibration: summary.model.vector_calibration.clone(),
        ..truth(&log)
    };
    let by_hand = magcomp::diagnose::heldout_rms(
        &log,
        &sensor,
        channel,
        &windows,
        &magcomp::model::ModelSpec::new(options.terms, hand),
        &options.fit,
    )
    .unwrap();
    [summary.heldout_rms_baseline_nt, summary.heldout_rms_final_nt, by_hand]
}

#[test]
fn a_diagnosed_model_holds_out_about_as_well_as_the_truth_modelled_by_hand() {
    use magcomp::model::{column_level, Extensions, SourceTerm};
    let coupling = |column: &'static str| {
        move |log: &magcomp::ingest::flight_log::FlightLog| Extensions {
            sources: vec![SourceTerm::AuxCoupling {
                column: column.into(),
                level: column_level(&log.channel(column).unwrap().values),
            }],
            ..Extensions::default()
        }
    };
    let cases: Vec<(&str, &str, [f64; 3])> = vec![
        (
            "concealed_a.csv",
            "mag_2_uc",
            diagnosed_and_by_hand("concealed_a.csv", "mag_2_uc", |_| Extensions {
                lag_s: 0.15,
                ..Extensions::default()
            }),
        ),
        (
            "concealed_b.csv",
            "mag_1_uc",
            diagnosed_and_by_hand("concealed_b.csv", "mag_1_uc", coupling("cur_com1")),
        ),
        (
            "concealed_b.csv",
            "mag_2_uc",
            diagnosed_and_by_hand("concealed_b.csv", "mag_2_uc", coupling("trim_tab")),
        ),
        (
            "concealed_c.csv",
            "mag_2_uc",
            diagnosed_and_by_hand("concealed_c.csv", "mag_2_uc", |_| Extensions {
                eddy_tau_s: 0.4,
                ..Extensions::default()
            }),
        ),
    ];
    // Measured (plain → diagnosed, by hand): concealed_a cabin 0.55 →
    // 0.0313, 0.0325 nT (lag 0.153 s found); concealed_b tail 0.113 →
    // 0.0237, 0.0237 nT, cabin 0.323 → 0.0407, 0.0407 nT; concealed_c
    // cabin 0.130, 0.143 nT (τ 0.36 s found). The fitted parameters are
    // chosen on held-out data, so they may beat the true ones slightly;
    // within their tolerances (lag ±0.03 s, τ ±20 %) they cost a few per
    // cent, so 10 % above the truth is the bound.
    for (flight, channel, [plain, diagnosed, by_hand]) in cases {
        assert!(
            by_hand < 0.5 * plain,
            "{flight} {channel}: the truth {by_hand} against plain {plain}"
        );
        assert!(
            diagnosed <= 1.1 * by_hand,
            "{flight} {channel}: diagnosed {diagnosed} nT, the truth by hand {by_hand} nT"
        );
    }
}

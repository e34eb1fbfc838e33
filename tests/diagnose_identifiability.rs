//! Effects that look alike stay distinct.
//!
//! - A current that follows the manoeuvres (the aileron servo draws
//!   0.3 A + 0.06 A per °/s of roll rate) against the eddy terms, which
//!   also follow the rates: a coupled servo is named as `aux_coupling`
//!   from `cur_ail`, and a lagged eddy response as `eddy_time_constant`,
//!   never the other way round.
//! - A scalar lag against an eddy time constant: a lag delays everything
//!   the sensor sees, an eddy time constant only the eddy part.
//!
//! Each flight has the campaign's tail, cabin and wing sensors.

mod common;

use magcomp::diagnose::Diagnosis;

fn diagnose(seed: u64, effects: &str) -> Diagnosis {
    common::diagnose_simulated(&common::three_sensor_scenario(seed, effects))
}

/// (effect, source) of every finding on `channel`.
fn named(diagnosis: &Diagnosis, channel: &str) -> Vec<(String, Option<String>)> {
    diagnosis
        .findings
        .iter()
        .filter(|f| f.channel == channel)
        .map(|f| (f.effect.name().to_string(), f.source.clone()))
        .collect()
}

#[test]
fn a_servo_current_is_not_taken_for_an_eddy_time_constant() {
    for seed in [41, 42] {
        let diagnosis = diagnose(
            seed,
            r#"
            [[effect]]
            kind = "aux_coupling"
            channel = "mag_2_uc"
            source = "cur_ail"
            nt_per_unit = [3.0, -2.0, 2.5]
            "#,
        );
        let cabin = named(&diagnosis, "mag_2_uc");
        assert!(
            cabin.contains(&("aux_coupling".into(), Some("cur_ail".into()))),
            "seed {seed}: {cabin:?}"
        );
        assert!(
            !cabin.iter().any(|(e, _)| e == "eddy_time_constant"),
            "seed {seed}: {cabin:?}"
        );
    }
}

#[test]
fn an_eddy_time_constant_is_not_taken_for_a_servo_current() {
    for (seed, tau_s) in [(41, 0.5), (42, 0.3)] {
        let diagnosis = diagnose(
            seed,
            &format!("[[effect]]\nkind = \"eddy_time_constant\"\nchannel = \"mag_2_uc\"\ntau_s = {tau_s}\n"),
        );
        let cabin: Vec<&magcomp::diagnose::Finding> =
            diagnosis.findings.iter().filter(|f| f.channel == "mag_2_uc").collect();
        assert_eq!(
            cabin.first().map(|f| f.effect.name()),
            Some("eddy_time_constant"),
            "seed {seed}: {cabin:#?}"
        );
        let tau = cabin[0].effect.parameters()["tau_s"];
        assert!((tau - tau_s).abs() < 0.2 * tau_s, "seed {seed}: τ {tau} for {tau_s}");
        assert!(
            !cabin.iter().any(|f| f.source.as_deref() == Some("cur_ail")),
            "seed {seed}: {cabin:#?}"
        );
    }
}

#[test]
fn a_lag_is_not_taken_for_an_eddy_time_constant_nor_the_reverse() {
    // On the cabin sensor, whose large aircraft field makes both show (on
    // this seed's cabin sensor a 0.2 s lag gains only 18 %, under the
    // threshold: a matter of power, not of telling the two apart).
    let lagged = diagnose(
        43,
        "[[effect]]\nkind = \"sensor_lag\"\nchannel = \"mag_2_uc\"\nlag_s = 0.2\n",
    );
    let cabin = named(&lagged, "mag_2_uc");
    assert_eq!(cabin.first().map(|(e, _)| e.as_str()), Some("sensor_lag"), "{cabin:?}");
    assert!(!cabin.iter().any(|(e, _)| e == "eddy_time_constant"), "{cabin:?}");
    let eddy = diagnose(
        43,
        "[[effect]]\nkind = \"eddy_time_constant\"\nchannel = \"mag_2_uc\"\ntau_s = 0.6\n",
    );
    let cabin = named(&eddy, "mag_2_uc");
    assert_eq!(
        cabin.first().map(|(e, _)| e.as_str()),
        Some("eddy_time_constant"),
        "{cabin:?}"
    );
    assert!(!cabin.iter().any(|(e, _)| e == "sensor_lag"), "{cabin:?}");
}

#[test]
fn a_short_eddy_time_constant_on_the_wing_is_not_taken_for_a_lag() {
    // The wing sensor's aircraft field is a tenth of the cabin's, and a τ
    // of two samples looks most like a lag. Blocked PRESS alone shrank the
    // lagged eddy terms so hard that a 0.19 s lag won (held out 0.033 nT
    // against 0.049 nT); scored under PRESS as well, the eddy τ holds out
    // 0.012 nT and is named.
    let eddy = diagnose(
        1001,
        "[[effect]]\nkind = \"eddy_time_constant\"\nchannel = \"mag_3_uc\"\ntau_s = 0.2\n",
    );
    let wing: Vec<_> = eddy.findings.iter().filter(|f| f.channel == "mag_3_uc").collect();
    assert_eq!(wing.len(), 1, "{wing:?}");
    assert_eq!(wing[0].effect.name(), "eddy_time_constant", "{wing:?}");
    let tau_s = wing[0].effect.parameters()["tau_s"];
    assert!((tau_s - 0.2).abs() < 0.2 * 0.2, "τ {tau_s} s");
}

#[test]
fn the_residual_a_clean_cabin_sensor_leaves_is_not_unexplained() {
    // On these clean flights the cabin sensor's first-order fit leaves
    // structured residual in several manoeuvres (0.041, 0.054 and
    // 0.089 nT held out), which the total field's second-order term takes
    // to 0.033, 0.014 and 0.046 nT: physics the library knows, not an
    // `unexplained` finding. On seed 511 what is left after it sits in the
    // rolls of two headings, each predicted by a fit that never saw its
    // heading (0.22 and 0.15 nT held out before the term); a fit on every
    // heading leaves no such structure, so it is the held-out fit's
    // extrapolation, not missing physics.
    for seed in [511, 517, 521] {
        let diagnosis = diagnose(seed, "");
        let cabin = diagnosis.channels.iter().find(|c| c.channel == "mag_2_uc").unwrap();
        assert!(
            cabin.heldout_rms_second_order_nt < cabin.heldout_rms_final_nt,
            "seed {seed}: {cabin:?}"
        );
        // The second-order term, where it pays held out, is a finding
        // like any other: the simulated scalar reads the total field, so
        // it is real physics here.
        let named: Vec<_> = diagnosis
            .findings
            .iter()
            .filter(|f| !matches!(f.effect.name(), "external_field" | "second_order"))
            .collect();
        assert!(named.is_empty(), "seed {seed}: {named:#?}");
    }
}

#[test]
fn unrelated_columns_do_not_stand_in_for_anything() {
    // Twenty-two slow columns that nothing magnetic follows, on top of the
    // simulator's eight: each is one more chance for a column to fit, by
    // its levels from leg to leg, residual it did not cause. Before the
    // shifted-columns test (`beats_shifted_sources`) the cabin sensor took
    // one of them as a coupling on seeds 506 and 515 (held-out −45 % and
    // −36 %, past the 30 % threshold).
    //
    // The simulator's own columns are not what this test is about: on seed
    // 509 the cabin sensor takes `cur_ail`, the aileron servo's current,
    // which follows the roll rate (held out 0.023 → 0.014 nT, twice the
    // noise floor). What it stands in for is the fluxgate's own aircraft
    // field, which bends the direction cosines the cabin's few hundred nT
    // are projected on: with the fluxgate's field left out of the flight
    // the finding is gone and the second-order term alone leaves
    // 0.015 nT. (The 18 terms' isotropic eddy column, d|B|/dt of the
    // fluxgate's field, took it before; the default leaves it out.)
    let mut spurious = Vec::new();
    for seed in 500..516 {
        let flight = magcomp::simulate::simulate(&common::three_sensor_scenario(seed, "")).unwrap();
        let diagnosis = common::diagnose_log(&common::with_unrelated_columns(&flight.log, 22));
        spurious.extend(
            diagnosis
                .findings
                .iter()
                .filter(|f| f.effect.name() == "aux_coupling")
                .filter(|f| f.source.as_deref().is_some_and(|s| s.starts_with("aux_")))
                .map(|f| format!("seed {seed}: {} on {} from {:?}", f.effect, f.channel, f.source)),
        );
    }
    assert!(spurious.is_empty(), "{spurious:#?}");
}

#[test]
fn a_current_acting_through_its_rate_of_change_is_named_with_both_vectors() {
    // The aileron servo's current reaches the cabin sensor directly and
    // through the eddy currents its changes induce (nT per A/s). Its rate
    // follows the roll acceleration, which no Tolles-Lawson term does; the
    // current itself follows the roll rate, as the eddy terms do, so its
    // direct vector shares part of its signal with them. Measured on these
    // seeds: rate vectors within 0.09 nT·s/A, direct vectors within
    // 0.41 nT/A, held-out 1.0–3.5 nT → 0.09–0.22 nT.
    let (k_true, kdot_true) = ([2.0, -1.0, 3.0], [3.0, 2.0, -4.0]);
    for seed in [41, 42, 43] {
        let diagnosis = diagnose(
            seed,
            &format!(
                "[[effect]]\nkind = \"aux_coupling\"\nchannel = \"mag_2_uc\"\nsource = \"cur_ail\"\nnt_per_unit = {k_true:?}\nnt_per_unit_per_s = {kdot_true:?}\n"
            ),
        );
        assert_eq!(
            named(&diagnosis, "mag_2_uc"),
            vec![("aux_coupling".to_string(), Some("cur_ail".to_string()))],
            "seed {seed}: {:#?}",
            diagnosis.findings
        );
        let finding = diagnosis.findings.iter().find(|f| f.channel == "mag_2_uc").unwrap();
        for (axis, (k, kdot)) in ["x", "y", "z"].iter().zip(k_true.iter().zip(kdot_true)) {
            let found_k = finding.effect.parameters()[&format!("k_{axis}_nt_per_unit")];
            let found_kdot = finding.effect.parameters()[&format!("kdot_{axis}_nt_s_per_unit")];
            assert!(
                (found_kdot - kdot).abs() < 0.15,
                "seed {seed} {axis}: rate {found_kdot} vs {kdot}"
            );
            assert!((found_k - k).abs() < 0.5, "seed {seed} {axis}: {found_k} vs {k}");
        }
        // Held out, the finding leaves under a quarter of a nT of the
        // 1-3.5 nT the model without it leaves (with the default's 16
        // terms, seed 42: 2.09 → 0.22 nT).
        assert!(
            finding.heldout_rms_before_nt > 1.0 && finding.heldout_rms_after_nt < 0.25,
            "{finding:?}"
        );
    }
}

#[test]
fn a_current_without_a_rate_effect_is_not_given_one() {
    // The same servo current acting directly only: the rate terms must
    // earn their place like any other effect (`drop_unearned_rates`).
    for seed in [41, 42] {
        let diagnosis = diagnose(
            seed,
            "[[effect]]\nkind = \"aux_coupling\"\nchannel = \"mag_2_uc\"\nsource = \"cur_ail\"\nnt_per_unit = [2.0, -1.0, 3.0]\n",
        );
        let finding = diagnosis.findings.iter().find(|f| f.channel == "mag_2_uc").unwrap();
        assert_eq!(finding.source.as_deref(), Some("cur_ail"), "{finding:?}");
        assert!(
            !finding.effect.parameters().contains_key("kdot_x_nt_s_per_unit"),
            "seed {seed}: {finding:?}"
        );
    }
}

/// A residual far above the noise floor is `unexplained`, spread or not:
/// the aileron servo's field reaches the tail sensor (2 nT per A on each
/// axis) but its current is not in the file, so nothing recorded can
/// explain it, and what it leaves follows every roll rather than standing
/// out in a few stretches. The diagnosis names it with the residual's
/// ratio to the noise floor (over 50, the factor the diagnosis states) and where it is
/// largest (rolls first), and the default run warns. Clean flights of the
/// same seeds keep no `unexplained` finding.
#[test]
fn a_residual_far_above_the_noise_is_unexplained_even_when_spread() {
    for seed in [521, 522] {
        let scenario = common::three_sensor_scenario(
            seed,
            r#"
            [[effect]]
            kind = "aux_coupling"
            channel = "mag_1_uc"
            source = "cur_ail"
            nt_per_unit = [2.0, 2.0, 2.0]
            "#,
        );
        let flight = magcomp::simulate::simulate(&scenario).unwrap();
        let channels = (flight.log.channels().iter())
            .filter(|c| c.name != "cur_ail")
            .cloned()
            .collect();
        let log = magcomp::ingest::flight_log::FlightLog::new(
            flight.log.source(),
            flight.log.time_column(),
            flight.log.time_s().to_vec(),
            channels,
        )
        .unwrap();
        let diagnosis = common::diagnose_log(&log);
        let tail: Vec<_> = diagnosis.findings.iter().filter(|f| f.channel == "mag_1_uc").collect();
        let unexplained: Vec<_> = tail.iter().filter(|f| f.effect.name() == "unexplained").collect();
        assert_eq!(unexplained.len(), 1, "seed {seed}: {tail:#?}");
        let ratio = unexplained[0].effect.parameters()["residual_to_noise"];
        assert!(ratio > 50.0, "seed {seed}: {ratio}");
        assert!(
            unexplained[0].located.iter().any(|l| l.label.contains("roll")),
            "seed {seed}: {:?}",
            unexplained[0].located
        );
        println!("seed {seed}: {}", unexplained[0].explanation);
        let clean = diagnose(seed, "");
        assert!(
            clean.findings.iter().all(|f| f.effect.name() != "unexplained"),
            "seed {seed}: {:#?}",
            clean.findings
        );
    }
}

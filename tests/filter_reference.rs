//! The zero-phase Butterworth filter against scipy.
//!
//! Reference values come from `tests/reference_scripts/butterworth_reference.py`
//! (scipy.signal.butter with output="sos", then sosfiltfilt with its default
//! odd padding). Coefficients agree to 1e-12 (scipy and sci-rs follow the same
//! zpk → bilinear → sos algorithm; differences are rounding), and the filtered
//! test vector to 1e-9 of its unit-scale amplitude.

use magcomp::numerics::filter::{EdgePadding, FilterBand, ZeroPhaseFilter};
use sci_rs::signal::filter::design::{butter_dyn, DigitalFilter, FilterBandType, FilterOutputType};

const BANDPASS_SOS: [f64; 24] = [
    0.002234891698082327,
    0.004469783396164654,
    0.002234891698082327,
    1.0,
    -1.2850126432444133,
    0.4387649162553223,
    1.0,
    2.0,
    1.0,
    1.0,
    -1.4603171736403668,
    0.716955991560341,
    1.0,
    -2.0,
    1.0,
    1.0,
    -1.8696631749453867,
    0.8751934078136212,
    1.0,
    -2.0,
    1.0,
    1.0,
    -1.9565142836160259,
    0.9605568000834551,
];
const BANDPASS_FILTERED: [f64; 60] = [
    -0.248587830234396,
    0.2860905994538774,
    0.7970716591021358,
    1.2654072979070223,
    1.674083984767551,
    2.0079085888678807,
    2.2537774588962067,
    2.4016220125497414,
    2.445273984217334,
    2.382486026340249,
    2.2143816151179596,
    1.945252200607126,
    1.5829785068537996,
    1.1393168631202533,
    0.6293004741214294,
    0.07005791598738198,
    -0.5199962013798984,
    -1.1212825520646095,
    -1.7132149800492595,
    -2.2751198158116503,
    -2.7876012066335796,
    -3.233397017024176,
    -3.5974199419586292,
    -3.866726466299985,
    -4.03115941106605,
    -4.084367199455077,
    -4.024256119052028,
    -3.8525725612671087,
    -3.574351441490965,
    -3.1979658490599574,
    -2.735474279932087,
    -2.2023291676419725,
    -1.6161749186070917,
    -0.9955317127512118,
    -0.35918581214864487,
    0.2739196969479154,
    0.8851443909030472,
    1.457187984511691,
    1.974934499309902,
    2.42539106618932,
    2.797111759247409,
    3.0801801671747633,
    3.267176303834294,
    3.354450396490993,
    3.3429098000642035,
    3.238416194595118,
    3.0523880441958733,
    2.8024725947723343,
    2.512138759934837,
    2.2082238609861173,
    1.916837761090227,
    1.6590855031402052,
    1.4478083281605567,
    1.2857049331695471,
    1.1650799527601086,
    1.0699967232908554,
    0.9813873407460609,
    0.8840058926731458,
    0.7722525467524424,
    0.6517539672556636,
];
const LOWPASS_SOS: [f64; 6] = [
    0.020083365564211232,
    0.040166731128422464,
    0.020083365564211232,
    1.0,
    -1.5610180758007182,
    0.6413515380575631,
];
const LOWPASS_FILTERED: [f64; 60] = [
    10.038170844390512,
    10.569451033870733,
    11.085684072533734,
    11.570086234821439,
    12.009565915069015,
    12.390324252634343,
    12.696849851755145,
    12.916459260086517,
    13.0437202765506,
    13.079097400973108,
    13.023977916126464,
    12.879070849337179,
    12.64834311303128,
    12.342843612479182,
    11.978769284860975,
    11.571946754083204,
    11.135737028374214,
    10.684542059040915,
    10.23727713385623,
    9.815174276371199,
    9.436098993363231,
    9.112393441075149,
    8.854427123702404,
    8.674217854597984,
    8.583483331870148,
    8.588297385333297,
    8.687352467006926,
    8.875995166981452,
    9.150380809294461,
    9.506089034940734,
    9.933354852298928,
    10.415896689012909,
    10.935488404497784,
    11.476602366820769,
    12.025448032291914,
    12.565545063950799,
    13.076799561218667,
    13.54022024199167,
    13.942594668534676,
    14.275446214898444,
    14.53041042782566,
    14.698002351603737,
    14.77191803813332,
    14.753200107601506,
    14.64860129489986,
    14.46530150594605,
    14.208970774302887,
    13.887346587676776,
    13.513685777042692,
    13.104461096840371,
    12.673500918527012,
    12.22961477149857,
    11.77993140101891,
    11.333375347263194,
    10.898724265199343,
    10.479520826376723,
    10.072955481864854,
    9.675010287459221,
    9.286331534564212,
    8.913277314732815,
];

fn test_vector() -> Vec<f64> {
    (0..60)
        .map(|k| {
            let t = k as f64 / 10.0;
            let tau = 2.0 * std::f64::consts::PI;
            3.0 * (tau * 0.3 * t).sin() + (tau * 2.0 * t).sin() + 0.5 * t + 10.0
        })
        .collect()
}

fn design_sos(order: usize, corners: Vec<f64>, band: FilterBandType) -> Vec<f64> {
    let DigitalFilter::Sos(design) = butter_dyn(
        order,
        corners,
        Some(band),
        Some(false),
        Some(FilterOutputType::Sos),
        Some(10.0),
    ) else {
        panic!("sections expected")
    };
    design
        .sos
        .iter()
        .flat_map(|s| [s.b[0], s.b[1], s.b[2], s.a[0], s.a[1], s.a[2]])
        .collect()
}

fn assert_close(found: &[f64], expected: &[f64], tolerance: f64) {
    assert_eq!(found.len(), expected.len());
    for (k, (a, b)) in found.iter().zip(expected).enumerate() {
        assert!((a - b).abs() < tolerance, "element {k}: {a} vs scipy {b}");
    }
}

#[test]
fn bandpass_design_matches_scipy() {
    assert_close(
        &design_sos(4, vec![0.1, 0.9], FilterBandType::Bandpass),
        &BANDPASS_SOS,
        1e-12,
    );
}

#[test]
fn lowpass_design_matches_scipy() {
    assert_close(&design_sos(2, vec![0.5], FilterBandType::Lowpass), &LOWPASS_SOS, 1e-12);
}

#[test]
fn bandpass_sosfiltfilt_matches_scipy() {
    let band = FilterBand::Bandpass {
        low_hz: 0.1,
        high_hz: 0.9,
    };
    let filter = ZeroPhaseFilter::butterworth(band, 4, 10.0, EdgePadding::Scipy).unwrap();
    assert_eq!(filter.pad(), 27);
    assert_close(&filter.apply(&test_vector()).unwrap(), &BANDPASS_FILTERED, 1e-9);
}

#[test]
fn lowpass_sosfiltfilt_matches_scipy() {
    let filter =
        ZeroPhaseFilter::butterworth(FilterBand::Lowpass { high_hz: 0.5 }, 2, 10.0, EdgePadding::Scipy).unwrap();
    assert_close(&filter.apply(&test_vector()).unwrap(), &LOWPASS_FILTERED, 1e-9);
}

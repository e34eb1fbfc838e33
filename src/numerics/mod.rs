//! The numerical core: zero-phase band-pass filtering ([`filter`]), the
//! small dense factorisations ([`linalg`]), runs of valid samples
//! ([`segments`]), stacked and band-passed design columns with the scratch
//! pool their memory comes from ([`stacked`]), and the regularised least
//! squares every model is fitted by ([`solve`]: ridge with λ by PRESS,
//! truncated SVD), with the rest of the estimator family side by side
//! ([`estimators`]: least squares, damped TSVD, TLS, truncated TLS), and
//! the plain statistics of a slice ([`statistics`]). Nothing here knows
//! about flights, sensors or files.

pub mod estimators;
pub mod filter;
pub mod linalg;
pub mod segments;
pub mod solve;
pub mod stacked;
pub mod statistics;

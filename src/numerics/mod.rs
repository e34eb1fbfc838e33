//! The numerical core: zero-phase band-pass filtering ([`filter`]), the
//! small dense factorisations ([`linalg`]), runs of valid samples
//! ([`segments`]), stacked and band-passed design columns with the scratch
//! pool their memory comes from ([`stacked`]), and the regularised least
//! squares every model is fitted by ([`solve`]: ridge with λ by PRESS,
//! truncated SVD). Nothing here knows about flights, sensors or files.

pub mod filter;
pub mod linalg;
pub mod segments;
pub mod solve;
pub mod stacked;

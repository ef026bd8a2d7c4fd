//! The core library's integration tests: one binary (ripgrep style), synthetic clouds made in
//! code, no external files.

mod accel_agree;
mod analytic;
mod determinism;
mod footprint;
mod ground;
mod lights;
mod materials;
mod multires;
mod path;
mod surfaces;
mod util;

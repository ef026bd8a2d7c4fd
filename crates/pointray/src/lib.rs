//! pointray: multiresolution ray tracing of point-based geometry.
//!
//! The pipeline, one module per stage:
//!
//! ```text
//! PointCloud ──preprocess──▶ PointCloud with normals + radii ──splats_from_cloud──▶ [Splat]
//!     ──accel (BruteForce | Bvh | KdTree)──▶ Accel ──render (camera, surface scheme, shading)──▶ Film + Stats
//! ```
//!
//! File formats live in `pointray-io`, the command line in `pointray-cli`; this crate has no
//! I/O and no global state (but for each thread's reusable BVH traversal stack).

pub mod accel;
pub mod camera;
pub mod camera_path;
pub mod clip;
pub mod cloud;
pub mod color;
pub mod color_by;
pub mod culling;
pub mod demo;
pub mod env_map;
pub mod eye_dome;
pub mod film;
pub mod frame;
pub mod ground;
pub mod knn;
pub mod material;
pub mod math;
pub mod mesh_sampling;
pub mod metrics;
pub mod preprocess;
pub mod progressive;
pub mod render;
pub mod scene;
pub mod settings;
pub mod shading;
pub mod splat;
pub mod stats;

pub use cloud::PointCloud;
pub use frame::Frame;
pub use scene::{RenderError, Scene, SceneParts, render};
pub use settings::Settings;

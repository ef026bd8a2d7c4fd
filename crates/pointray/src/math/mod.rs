//! Geometry primitives shared by every stage: bounds, rays with footprints, the 3×3 symmetric
//! eigen solver used by PCA, orthonormal frames and Morton codes.

mod bounds;
pub mod eigen;
pub mod morton;
mod ray;
pub mod select;

pub use bounds::Aabb;
pub use glam::{DVec3, Vec3};
pub use ray::{Ray, RayCone, RayLanes};

/// Two unit vectors orthogonal to `n` and to each other (Duff et al. 2017, branchless).
pub fn orthonormal_basis(n: Vec3) -> (Vec3, Vec3) {
    let sign = 1f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x), Vec3::new(b, sign + n.y * n.y * a, -n.y))
}

//! The point-set surface (PSS): the moving least-squares surface of Adamson & Alexa (2003,
//! RECONSTRUCTION A11, C3), in its weighted-average form. Near a point x, the splats within a
//! few bandwidths h weigh θᵢ = exp(−|x − pᵢ|²/h²); their weighted centre a(x) and normal n(x)
//! define a plane, and the surface is where x lies on its own plane, n(x)·(x − a(x)) = 0.
//!
//! A ray reaches it by projection steps from a seed, the SJ hit: at x = o + t·d it moves to
//! the crossing of its plane, t ← (a − o)·n / (d·n), until a step is below the tolerance.
//! Neighbours come from the accelerator's radius query (`Accel::for_each_near`). Only splats
//! whose normals face the same way as the seed's count, so the other side of a thin part does
//! not pull the surface into its middle. A step that finds no neighbours, meets its plane
//! edge-on, wanders more than a few bandwidths from the seed, or does not converge within the
//! cap leaves the seed as the hit (counted in `TraversalStats::pss_fallbacks`).

use glam::{DVec3, Vec3};

use super::scheme::{SurfaceHit, facing};
use crate::accel::{Accel, TraversalStats};
use crate::math::Ray;

#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct PssParams {
    /// Bandwidth h in units of the seed disk's radius.
    pub bandwidth: f32,
    /// Neighbours are gathered within this many bandwidths (the weight there is exp(−c²)).
    pub support: f32,
    /// Converged when a step moves less than this, in units of the seed disk's radius.
    pub tolerance: f32,
    /// Most projection steps per hit.
    pub max_steps: u32,
}

impl PssParams {
    pub fn standard() -> Self {
        Self { bandwidth: 1.0, support: 2.5, tolerance: 1e-3, max_steps: 8 }
    }
}

/// Where the plane of a projection step meets the ray at a grazing angle of more than about
/// 84°, the step is no longer trusted.
const MIN_COS: f32 = 0.1;

/// The PSS hit near `seed` (an SJ hit on the same ray); the seed itself if the projection
/// fails.
pub fn project<A: Accel + ?Sized>(
    accel: &A,
    ray: &Ray,
    seed: &SurfaceHit,
    params: &PssParams,
    stats: &mut TraversalStats,
) -> SurfaceHit {
    let h = params.bandwidth * seed.radius;
    let tolerance = params.tolerance * seed.radius;
    // The side: the seed disk's own normal, as stored (the hit's normal is turned to the ray,
    // and a ray meeting the surface from behind would otherwise find no neighbour on its side).
    let side = accel.splat(seed.splat).normal;
    let mut t = seed.t;
    for _ in 0..params.max_steps {
        stats.pss_steps += 1;
        let Some(plane) = local_plane(accel, ray.at(t), h, params.support * h, side, stats) else { break };
        let den = ray.dir.dot(plane.normal);
        if den.abs() < MIN_COS {
            break;
        }
        let next = (plane.center - ray.origin).dot(plane.normal) / den;
        if !(next >= ray.t_min && (next - seed.t).abs() <= params.support * h) {
            break;
        }
        let step = (next - t).abs();
        t = next;
        if step < tolerance {
            // Shaded with this step's plane: the next one would differ by less than the tolerance.
            return SurfaceHit {
                t,
                position: ray.at(t),
                normal: facing(plane.normal, ray.dir),
                color: plane.color,
                blended: plane.count,
                ..*seed
            };
        }
    }
    stats.pss_fallbacks += 1;
    *seed
}

/// The weighted centre, normal and colour of the splats near `x`.
struct LocalPlane {
    center: Vec3,
    normal: Vec3,
    color: [f32; 3],
    count: u32,
}

/// The MLS plane at `x`: Gaussian weights of bandwidth `h` over the splats within `support`
/// whose normals lie in the hemisphere of `side`; `None` if none has weight.
///
/// Each accelerator reports the neighbours in its own order; the sums run in f64, where the
/// order almost never shows once they are rounded to f32 (not guaranteed: the agreement tests
/// check that accelerators match bit for bit on their rays).
fn local_plane<A: Accel + ?Sized>(
    accel: &A,
    x: Vec3,
    h: f32,
    support: f32,
    side: Vec3,
    stats: &mut TraversalStats,
) -> Option<LocalPlane> {
    let (mut wsum, mut center, mut normal, mut color, mut count) = (0.0, DVec3::ZERO, DVec3::ZERO, DVec3::ZERO, 0);
    accel.for_each_near(x, support, stats, |_, s| {
        if s.normal.dot(side) <= 0.0 {
            return;
        }
        let w = f64::from((-(s.center - x).length_squared() / (h * h)).exp());
        wsum += w;
        center += w * s.center.as_dvec3();
        normal += w * s.normal.as_dvec3();
        color += w * Vec3::from(s.color_linear()).as_dvec3();
        count += 1;
    });
    if wsum <= 0.0 || normal.length_squared() == 0.0 {
        return None;
    }
    Some(LocalPlane {
        center: (center / wsum).as_vec3(),
        normal: normal.normalize().as_vec3(),
        color: (color / wsum).as_vec3().to_array(),
        count,
    })
}

//! `PointCloud`: the scanned points and whatever per-point attributes the input had.

use glam::{DVec3, Vec3};

use crate::math::Aabb;

/// A point set in structure-of-arrays form. Attributes the input lacks are `None` and are
/// filled in by [`crate::preprocess`].
///
/// Positions are stored in `f32` relative to `origin` (kept in `f64`), so that scans far from
/// the coordinate origin (LiDAR in state-plane feet, say) keep their precision:
/// world position = `origin + position`.
#[derive(Clone, Debug, Default)]
pub struct PointCloud {
    pub positions: Vec<Vec3>,
    /// Unit normals. Not necessarily consistently oriented until `preprocess::orient` ran.
    pub normals: Option<Vec<Vec3>>,
    /// Splat radii, in the same units as `positions`.
    pub radii: Option<Vec<f32>>,
    /// Colours as stored in the file (sRGB-encoded), each channel in `[0, 1]`.
    pub colors: Option<Vec<[f32; 3]>>,
    /// Offset subtracted from every input coordinate (see the type's doc).
    pub origin: DVec3,
    /// Where the scanner stood, in the same local coordinates as `positions`, where the file
    /// says (an organised depth frame's PCD `VIEWPOINT`): computed normals are turned to face it.
    pub viewpoint: Option<Vec3>,
}

impl PointCloud {
    /// A cloud of bare positions, already local (origin zero).
    pub fn from_positions(positions: Vec<Vec3>) -> Self {
        Self { positions, ..Self::default() }
    }

    /// Builds a cloud from world coordinates in `f64`: recentres them on the bounding-box
    /// centre of the finite ones and stores `f32` offsets from it. Non-finite coordinates stay
    /// non-finite (preprocessing drops them); they do not move the origin. Neither do
    /// coordinates beyond `f32`'s range (±3.4·10³⁸), which become infinite.
    pub fn from_world_positions(world: &[DVec3]) -> Self {
        let (lo, hi) = world
            .iter()
            .filter(|p| p.abs().max_element() <= f64::from(f32::MAX))
            .fold((DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)), |(lo, hi), p| {
                (lo.min(*p), hi.max(*p))
            });
        let origin = if lo.x <= hi.x { (lo + hi) * 0.5 } else { DVec3::ZERO };
        let positions = world.iter().map(|p| (*p - origin).as_vec3()).collect();
        Self { positions, origin, ..Self::default() }
    }

    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Bounding box of the positions (not of the splats' disks).
    pub fn bounds(&self) -> Aabb {
        Aabb::from_points(self.positions.iter().copied())
    }

    /// Applies a permutation: element `i` of the result is element `order[i]` of `self`.
    pub fn permute(&mut self, order: &[u32]) {
        fn apply<T: Copy>(v: &mut Vec<T>, order: &[u32]) {
            *v = order.iter().map(|&i| v[i as usize]).collect();
        }
        apply(&mut self.positions, order);
        if let Some(n) = &mut self.normals {
            apply(n, order);
        }
        if let Some(r) = &mut self.radii {
            apply(r, order);
        }
        if let Some(c) = &mut self.colors {
            apply(c, order);
        }
    }

    /// Checks that every attribute has one entry per point.
    pub fn check_lengths(&self) -> Result<(), String> {
        let n = self.len();
        let check = |name: &str, len: Option<usize>| match len {
            Some(l) if l != n => Err(format!("{name} has {l} entries for {n} points")),
            _ => Ok(()),
        };
        check("normals", self.normals.as_ref().map(Vec::len))?;
        check("radii", self.radii.as_ref().map(Vec::len))?;
        check("colors", self.colors.as_ref().map(Vec::len))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recentres_on_the_finite_points() {
        let world =
            [DVec3::new(636_000.0, 10.0, 5.0), DVec3::new(636_002.0, 12.0, 7.0), DVec3::new(f64::INFINITY, 0.0, 0.0)];
        let cloud = PointCloud::from_world_positions(&world);
        assert_eq!(cloud.origin, DVec3::new(636_001.0, 11.0, 6.0));
        assert_eq!(cloud.positions[0], Vec3::new(-1.0, -1.0, -1.0));
        assert!(!cloud.positions[2].is_finite());
        assert_eq!(PointCloud::from_world_positions(&[DVec3::NAN]).origin, DVec3::ZERO);
        // Finite in f64, infinite in f32: it must not pull the others out of range.
        let cloud = PointCloud::from_world_positions(&[DVec3::ONE, DVec3::new(1e39, 0.0, 0.0), DVec3::splat(3.0)]);
        assert_eq!((cloud.origin, cloud.positions[0]), (DVec3::splat(2.0), Vec3::splat(-1.0)));
        assert!(cloud.positions[1].x.is_infinite());
    }
}

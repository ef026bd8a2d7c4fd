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
    /// What each position rounded off its world coordinates (world = `origin + position +
    /// residual`, summed in `f64`), kept for clouds wider than [`RESIDUALS_PAST`]: a scene in
    /// parts moves each point into its part's frame with it, so that each part keeps the
    /// precision of its own extent, not the cloud's.
    pub residuals: Option<Vec<Vec3>>,
    /// Where the scanner stood, in the same local coordinates as `positions`, where the file
    /// says: a position per scan (an organised depth frame's PCD `VIEWPOINT`, each E57 scan's
    /// pose). Computed normals are turned to face their point's scanner.
    pub viewpoints: Vec<Vec3>,
    /// Which of `viewpoints` saw each point (`None`: the first saw them all).
    pub viewpoint_of: Option<Vec<u16>>,
    /// What the scanner recorded of each point beside position and colour.
    pub scan: ScanAttributes,
}

/// Per-point values a scanner records (LAS/LAZ and E57 carry them; PLY, PCD and text files
/// where a column has one of their names), each `None` where the input has none. They ride
/// along through preprocessing; `color_by` turns one into colours and filters by class.
#[derive(Clone, Debug, Default)]
pub struct ScanAttributes {
    /// The return's strength, in the file's own units (LAS: 16-bit; E57: normalised by the
    /// file's limits to `[0, 1]`).
    pub intensity: Option<Vec<f32>>,
    /// The ASPRS class code (LAS; 2 ground, 6 building, …).
    pub classification: Option<Vec<u8>>,
    /// Which return of its pulse the point is (1 the first).
    pub return_number: Option<Vec<u8>>,
    /// When the point was recorded (LAS GPS time, seconds).
    pub gps_time: Option<Vec<f64>>,
}

impl ScanAttributes {
    /// Whether the input had none of them.
    pub fn is_empty(&self) -> bool {
        self.intensity.is_none()
            && self.classification.is_none()
            && self.return_number.is_none()
            && self.gps_time.is_none()
    }

    /// Each attribute present, by name, with its length.
    fn lengths(&self) -> [(&'static str, Option<usize>); 4] {
        [
            ("intensity", self.intensity.as_ref().map(Vec::len)),
            ("classification", self.classification.as_ref().map(Vec::len)),
            ("return_number", self.return_number.as_ref().map(Vec::len)),
            ("gps_time", self.gps_time.as_ref().map(Vec::len)),
        ]
    }

    fn permute(&mut self, order: &[u32]) {
        permute_some(&mut self.intensity, order);
        permute_some(&mut self.classification, order);
        permute_some(&mut self.return_number, order);
        permute_some(&mut self.gps_time, order);
    }

    /// Appends `other`'s values after this one's `len` points; an attribute only one side has
    /// is filled with zeros on the other. Values are kept in their files' units: a LAS file's
    /// raw intensity and an E57 file's normalised one end up on one scale.
    pub fn append(&mut self, len: usize, other: ScanAttributes, other_len: usize) {
        append_some(&mut self.intensity, len, other.intensity, other_len);
        append_some(&mut self.classification, len, other.classification, other_len);
        append_some(&mut self.return_number, len, other.return_number, other_len);
        append_some(&mut self.gps_time, len, other.gps_time, other_len);
    }
}

/// Half the extent (on an axis, in the file's units) past which a cloud keeps its positions'
/// [`PointCloud::residuals`]: `f32` offsets from its centre round by at most 2⁻¹² of a unit
/// within it (a quarter of a millimetre in metres), by 4 mm 100 km out.
pub const RESIDUALS_PAST: f64 = 4096.0;

/// Element `i` of the result is element `order[i]` of `v`.
fn permute_some<T: Copy>(v: &mut Option<Vec<T>>, order: &[u32]) {
    if let Some(v) = v {
        *v = order.iter().map(|&i| v[i as usize]).collect();
    }
}

/// `a` (of `len` points) followed by `b` (of `b_len`), zeros standing in for a missing side.
fn append_some<T: Copy + Default>(a: &mut Option<Vec<T>>, len: usize, b: Option<Vec<T>>, b_len: usize) {
    if a.is_none() && b.is_none() {
        return;
    }
    let a = a.get_or_insert_with(|| vec![T::default(); len]);
    a.extend(b.unwrap_or_else(|| vec![T::default(); b_len]));
}

/// The bounds of a cloud's finite world positions, whose centre is its origin
/// ([`PointCloud::from_world_positions`]; a cloud read in passes, `pointray_io::prepare`, finds
/// the same).
#[derive(Clone, Copy, Debug)]
pub struct WorldBounds {
    lo: DVec3,
    hi: DVec3,
}

impl Default for WorldBounds {
    fn default() -> Self {
        Self { lo: DVec3::splat(f64::INFINITY), hi: DVec3::splat(f64::NEG_INFINITY) }
    }
}

impl WorldBounds {
    /// With `p`, unless it is not finite or beyond f32's range.
    pub fn with(self, p: DVec3) -> Self {
        if p.abs().max_element() <= f64::from(f32::MAX) {
            Self { lo: self.lo.min(p), hi: self.hi.max(p) }
        } else {
            self
        }
    }

    /// Their centre (zero without a point).
    pub fn origin(&self) -> DVec3 {
        if self.lo.x <= self.hi.x { (self.lo + self.hi) * 0.5 } else { DVec3::ZERO }
    }

    /// Whether a cloud of these bounds keeps its [`PointCloud::residuals`].
    pub fn keeps_residuals(&self) -> bool {
        self.lo.x <= self.hi.x && ((self.hi - self.lo) * 0.5).max_element() > RESIDUALS_PAST
    }
}

/// The world coordinates a cloud of `origin` holds of a point at `position` with `residual`
/// ([`PointCloud::world_position`]).
pub fn held(origin: DVec3, position: Vec3, residual: Vec3) -> DVec3 {
    origin + position.as_dvec3() + residual.as_dvec3()
}

/// What `position` (of `world`, less `origin`) rounded off, as [`PointCloud::residuals`] keeps it.
pub fn residual(world: DVec3, origin: DVec3, position: Vec3) -> Vec3 {
    (world - origin - position.as_dvec3()).as_vec3()
}

/// `position` and its `residual` (in the cloud's frame) in the frame `offset` away, rounded once.
pub fn moved_precisely(position: Vec3, residual: Vec3, offset: Vec3) -> Vec3 {
    (position.as_dvec3() - offset.as_dvec3() + residual.as_dvec3()).as_vec3()
}

impl PointCloud {
    /// A cloud of bare positions, already local (origin zero).
    pub fn from_positions(positions: Vec<Vec3>) -> Self {
        Self { positions, ..Self::default() }
    }

    /// Builds a cloud from world coordinates in `f64`: recentres them on the bounding-box
    /// centre of the finite ones and stores `f32` offsets from it. Non-finite coordinates stay
    /// non-finite (preprocessing drops them); they do not move the origin. Neither do
    /// coordinates beyond `f32`'s range (±3.4·10³⁸), which become infinite. A cloud wider than
    /// [`RESIDUALS_PAST`] keeps what the `f32` offsets rounded off.
    pub fn from_world_positions(world: &[DVec3]) -> Self {
        let bounds = world.iter().fold(WorldBounds::default(), |b, p| b.with(*p));
        let origin = bounds.origin();
        let positions: Vec<Vec3> = world.iter().map(|p| (*p - origin).as_vec3()).collect();
        let residuals = bounds
            .keeps_residuals()
            .then(|| world.iter().zip(&positions).map(|(w, p)| residual(*w, origin, *p)).collect());
        Self { positions, origin, residuals, ..Self::default() }
    }

    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// Point `i`'s world coordinates, as the cloud holds them.
    pub fn world_position(&self, i: usize) -> DVec3 {
        held(self.origin, self.positions[i], self.residuals.as_ref().map_or(Vec3::ZERO, |r| r[i]))
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
        self.positions = order.iter().map(|&i| self.positions[i as usize]).collect();
        permute_some(&mut self.normals, order);
        permute_some(&mut self.radii, order);
        permute_some(&mut self.colors, order);
        permute_some(&mut self.viewpoint_of, order);
        permute_some(&mut self.residuals, order);
        self.scan.permute(order);
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
        check("colors", self.colors.as_ref().map(Vec::len))?;
        check("viewpoint_of", self.viewpoint_of.as_ref().map(Vec::len))?;
        check("residuals", self.residuals.as_ref().map(Vec::len))?;
        if let Some(&last) =
            self.viewpoint_of.iter().flatten().max().filter(|&&v| usize::from(v) >= self.viewpoints.len())
        {
            return Err(format!("viewpoint_of names viewpoint {last} of {}", self.viewpoints.len()));
        }
        self.scan.lengths().into_iter().try_for_each(|(name, len)| check(name, len))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scan_attributes_follow_their_points() {
        let mut cloud = PointCloud::from_positions(vec![Vec3::X, Vec3::Y, Vec3::Z]);
        cloud.scan.classification = Some(vec![2, 6, 9]);
        cloud.scan.gps_time = Some(vec![0.5, 1.5, 2.5]);
        cloud.permute(&[2, 0]);
        assert_eq!(cloud.scan.classification, Some(vec![9, 2]));
        assert_eq!(cloud.scan.gps_time, Some(vec![2.5, 0.5]));
        assert!(cloud.scan.intensity.is_none());
        cloud.check_lengths().unwrap();
        cloud.scan.return_number = Some(vec![1]);
        assert_eq!(cloud.check_lengths().unwrap_err(), "return_number has 1 entries for 2 points");
        let mut other = ScanAttributes { intensity: Some(vec![7.0]), ..ScanAttributes::default() };
        other.append(1, ScanAttributes { classification: Some(vec![5]), ..ScanAttributes::default() }, 1);
        assert_eq!((other.intensity, other.classification), (Some(vec![7.0, 0.0]), Some(vec![0, 5])));
    }

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
        assert!(cloud.residuals.is_none());
    }

    #[test]
    fn a_wide_cloud_keeps_what_its_positions_rounded_off() {
        // 200 km of UTM eastings on a tenth-of-a-millimetre lattice.
        let world: Vec<DVec3> =
            (0..1000).map(|i| DVec3::new(400_000.0 + i as f64 * 200.000_1, 5_000_000.0, 12.3456)).collect();
        let cloud = PointCloud::from_world_positions(&world);
        let residuals = cloud.residuals.as_ref().expect("wider than the limit");
        let rounded = |w: DVec3, p: Vec3| (w - cloud.origin - p.as_dvec3()).length();
        let worst = world.iter().zip(&cloud.positions).map(|(w, p)| rounded(*w, *p)).fold(0.0, f64::max);
        assert!(worst > 1e-3, "f32 alone rounds by {worst}");
        for ((w, p), r) in world.iter().zip(&cloud.positions).zip(residuals) {
            assert!((*w - cloud.origin - p.as_dvec3() - r.as_dvec3()).length() < 1e-9);
        }
        // Moved into a frame near the point, the point keeps the world's precision.
        let offset = cloud.positions[999] - Vec3::new(3.0, 0.0, 0.0);
        let moved = moved_precisely(cloud.positions[999], residuals[999], offset);
        assert!((cloud.origin + offset.as_dvec3() + moved.as_dvec3() - world[999]).length() < 1e-6);
        let narrow = PointCloud::from_world_positions(&world[..10]);
        assert!(narrow.residuals.is_none(), "2 km wide: f32 keeps a quarter of a millimetre");
    }
}

use glam::{Vec3, Vec4};

/// A ray's footprint cone: the width of the beam it stands for at distance `t` is
/// `width(t) = width0 + spread * t` (thesis §A5, ray cones after Amanatides 1984).
/// Primary rays start with `width0 = 0` and `spread` = the angular width of one pixel;
/// secondary rays start from the footprint at their origin. Level-of-detail selection compares a
/// node's size with this width.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RayCone {
    pub width0: f32,
    pub spread: f32,
}

impl RayCone {
    pub fn width_at(&self, t: f32) -> f32 {
        self.width0 + self.spread * t
    }

    /// The footprint `factor` times as wide everywhere (a sample's share of a pixel).
    #[inline(always)]
    #[must_use]
    pub fn scaled(self, factor: f32) -> Self {
        Self { width0: self.width0 * factor, spread: self.spread * factor }
    }
}

/// A ray `origin + t * dir` for `t` in `[t_min, ∞)`, with its footprint and what a
/// multiresolution accelerator may skip for it. `dir` is unit length; `inv_dir` is cached for
/// slab tests.
#[derive(Clone, Copy, Debug)]
pub struct Ray {
    pub origin: Vec3,
    pub dir: Vec3,
    pub inv_dir: Vec3,
    /// Hits closer than this are ignored (self-intersection guard for secondary rays).
    pub t_min: f32,
    pub cone: RayCone,
    /// Level-of-detail threshold τ in footprints (pixels, for camera rays): a subtree whose
    /// bounding sphere has radius R < τ·`cone.width_at(t)` is replaced by its representative
    /// splat. 0 = full detail.
    pub lod_threshold: f32,
    /// Subtrees whose disks all face away from `origin` may be skipped (normal-cone culling).
    /// Only for rays that cannot need a back face: rays from outside a closed, consistently
    /// oriented surface.
    pub cull_backfaces: bool,
}

impl Ray {
    /// `dir` need not be normalised; it is.
    pub fn new(origin: Vec3, dir: Vec3, cone: RayCone) -> Self {
        let dir = dir.normalize();
        Self { origin, dir, inv_dir: dir.recip(), t_min: 0.0, cone, lod_threshold: 0.0, cull_backfaces: false }
    }

    #[must_use]
    pub fn with_lod_threshold(mut self, tau: f32) -> Self {
        self.lod_threshold = tau;
        self
    }

    #[must_use]
    pub fn with_backface_culling(mut self, cull: bool) -> Self {
        self.cull_backfaces = cull;
        self
    }

    #[must_use]
    pub fn with_t_min(mut self, t_min: f32) -> Self {
        self.t_min = t_min;
        self
    }

    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }
}

/// `N` rays from one origin, held as lanes: [`Ray::new`] for `N` directions at once (`N` a
/// multiple of four), lane by lane in the same IEEE operations, so with the same bits, four to
/// an SSE instruction. One ray at a time, the latencies of a camera ray's root and six
/// divisions added up: a second camera ray for each sample cost 16 % of the dragon's distant
/// samples a second (64 a pixel, alternating runs).
pub struct RayLanes<const N: usize> {
    origin: Vec3,
    /// Component k of direction i in `dir[k][i]`, unit length.
    dir: [[f32; N]; 3],
    inv_dir: [[f32; N]; 3],
    cone: RayCone,
}

impl<const N: usize> RayLanes<N> {
    /// The rays from `origin` along `dir` (`dir[k][i]`: component k of direction i).
    pub fn new(origin: Vec3, dir: [[f32; N]; 3], cone: RayCone) -> Self {
        const { assert!(N.is_multiple_of(4)) };
        let (mut unit, mut inv_dir) = ([[0.0; N]; 3], [[0.0; N]; 3]);
        for i in (0..N).step_by(4) {
            let [x, y, z] = dir.map(|d| Vec4::from_slice(&d[i..i + 4]));
            // As `Vec3::normalize`: times the reciprocal of the length, the dot product summed
            // from x; then `recip`, a division per component.
            let length_recip = Vec4::ONE / (x * x + y * y + z * z).sqrt();
            for (k, d) in [x, y, z].into_iter().enumerate() {
                let u = d * length_recip;
                u.write_to_slice(&mut unit[k][i..i + 4]);
                u.recip().write_to_slice(&mut inv_dir[k][i..i + 4]);
            }
        }
        Self { origin, dir: unit, inv_dir, cone }
    }

    /// Ray `i`, as `Ray::new` makes it.
    #[inline(always)]
    pub fn ray(&self, i: usize) -> Ray {
        let (d, v) = (&self.dir, &self.inv_dir);
        Ray {
            origin: self.origin,
            dir: Vec3::new(d[0][i], d[1][i], d[2][i]),
            inv_dir: Vec3::new(v[0][i], v[1][i], v[2][i]),
            t_min: 0.0,
            cone: self.cone,
            lod_threshold: 0.0,
            cull_backfaces: false,
        }
    }
}

use glam::Vec3;

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

use super::{Accel, SplatVisitor, TraversalStats};
use crate::math::{Aabb, Ray};
use crate::splat::footprint::{Aggregate, Beam, FootprintVisitor, coverage_density, density_stride};
use crate::splat::{DiskShape, Splat};
use glam::Vec3;

/// Tests every splat against every ray: O(n) per ray, correct by construction, the oracle the
/// other accelerators are checked against.
pub struct BruteForce {
    splats: Vec<Splat>,
    bounds: Aabb,
    wide_radius: f32,
    /// [`Accel::coverage_density`], found when first asked (it costs O(n) a sample here).
    coverage_density: std::sync::OnceLock<f32>,
}

impl BruteForce {
    /// The oracle over `splats` as every accelerator stores them (`block::snap`).
    pub fn new(mut splats: Vec<Splat>) -> Self {
        super::block::snap(&mut splats);
        let bounds = splats.iter().fold(Aabb::EMPTY, |b, s| b.union(s.bounds()));
        let wide_radius = super::representative::wide_radius(&splats);
        Self { splats, bounds, wide_radius, coverage_density: std::sync::OnceLock::new() }
    }
}

impl Accel for BruteForce {
    fn name(&self) -> &'static str {
        "brute"
    }

    fn splat(&self, index: u32) -> Splat {
        self.splats[index as usize]
    }

    fn is_representative(&self, _index: u32) -> bool {
        false
    }

    fn splat_count(&self) -> usize {
        self.splats.len()
    }

    fn bounds(&self) -> Aabb {
        self.bounds
    }

    fn wide_radius(&self) -> f32 {
        self.wide_radius
    }

    fn coverage_density(&self) -> f32 {
        *self.coverage_density.get_or_init(|| {
            coverage_density(self, self.splats.iter().copied().step_by(density_stride(self.splats.len())))
        })
    }

    /// Every disk, at full detail.
    fn gather<V: FootprintVisitor>(&self, _beam: &Beam, _tau: f32, visitor: &mut V, stats: &mut TraversalStats) {
        for (i, s) in self.splats.iter().enumerate() {
            stats.splat_tests += 1;
            visitor.add(i as u32, s, Aggregate::disk(s.radius));
        }
    }

    /// No level of detail.
    fn lod_floor(&self) -> f32 {
        f32::INFINITY
    }

    /// No level of detail.
    fn may_stop_at_representatives(&self, _ray: &Ray) -> bool {
        false
    }

    /// Every splat reaches the visitor, whatever its shape.
    fn shape(&self) -> DiskShape {
        DiskShape::RayFacing
    }

    fn for_each_near<F: FnMut(u32, Splat)>(&self, center: Vec3, radius: f32, stats: &mut TraversalStats, mut f: F) {
        for (i, s) in self.splats.iter().enumerate() {
            stats.splat_tests += 1;
            if (s.center - center).length_squared() <= radius * radius {
                f(i as u32, *s);
            }
        }
    }

    fn memory_bytes(&self) -> usize {
        self.splats.len() * size_of::<Splat>()
    }

    fn traverse<V: SplatVisitor>(&self, ray: &Ray, visitor: &mut V, stats: &mut TraversalStats) {
        for (i, s) in self.splats.iter().enumerate() {
            stats.splat_tests += 1;
            super::test_disk(ray, s, i as u32, visitor);
            if visitor.done() {
                return;
            }
        }
    }
}

//! Counters of a render, summed per tile and merged once (integers: thread-count independent).

use crate::accel::TraversalStats;

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct RenderStats {
    /// All rays traced: primary, secondary and shadow.
    pub rays: u64,
    pub primary_rays: u64,
    /// Reflected and refracted rays.
    pub secondary_rays: u64,
    pub shadow_rays: u64,
    /// Primary rays that hit a splat (the ground plane's hits are not counted).
    pub primary_hits: u64,
    /// Disks blended into primary hits (SJ window sizes, summed).
    pub blended_splats: u64,
    pub traversal: TraversalStats,
}

impl std::ops::AddAssign for RenderStats {
    fn add_assign(&mut self, o: Self) {
        self.rays += o.rays;
        self.primary_rays += o.primary_rays;
        self.secondary_rays += o.secondary_rays;
        self.shadow_rays += o.shadow_rays;
        self.primary_hits += o.primary_hits;
        self.blended_splats += o.blended_splats;
        self.traversal += o.traversal;
    }
}

impl RenderStats {
    pub fn hit_fraction(&self) -> f64 {
        ratio(self.primary_hits, self.primary_rays)
    }

    pub fn nodes_visited_per_ray(&self) -> f64 {
        ratio(self.traversal.nodes_visited, self.rays)
    }

    pub fn splat_tests_per_ray(&self) -> f64 {
        ratio(self.traversal.splat_tests, self.rays)
    }
}

/// The median of sorted values (the mean of the middle two for an even count): frame times.
///
/// # Panics
/// If `sorted` is empty.
pub fn median(sorted: &[f64]) -> f64 {
    let n = sorted.len();
    if n % 2 == 1 { sorted[n / 2] } else { 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]) }
}

fn ratio(a: u64, b: u64) -> f64 {
    if b == 0 { 0.0 } else { a as f64 / b as f64 }
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_median_of_an_even_count_is_the_mean_of_the_middle_two() {
        assert_eq!(super::median(&[1.0, 2.0, 3.0]), 2.0);
        assert_eq!(super::median(&[1.0, 2.0, 4.0, 10.0]), 3.0);
        assert_eq!(super::median(&[5.0]), 5.0);
    }
}

//! k-nearest-neighbour queries: the only module that knows kiddo, so that our own kd-tree can
//! replace it later without touching the preprocessing.

use std::num::NonZeroUsize;

use glam::Vec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;

/// The `k` nearest neighbours of every point, stored flat (`n × k`), each row in ascending
/// distance, the point itself excluded. Coincident duplicates are ordinary neighbours at
/// distance zero.
#[derive(Clone, Debug, Default)]
pub struct Neighbourhoods {
    pub k: usize,
    pub indices: Vec<u32>,
    pub sq_dists: Vec<f32>,
}

impl Neighbourhoods {
    /// Indices of the neighbours of point `i`, nearest first.
    pub fn of(&self, i: usize) -> &[u32] {
        &self.indices[i * self.k..(i + 1) * self.k]
    }

    /// Squared distances matching [`Self::of`].
    pub fn sq_dists_of(&self, i: usize) -> &[f32] {
        &self.sq_dists[i * self.k..(i + 1) * self.k]
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.indices.len().checked_div(self.k).unwrap_or(0)
    }

    pub fn is_empty(&self) -> bool {
        self.indices.is_empty()
    }
}

/// A static spatial index over a point set, for queries at arbitrary locations.
pub struct PointIndex {
    tree: ImmutableKdTree<f32, 3>,
    len: usize,
}

impl PointIndex {
    /// Builds the index; positions must be finite.
    pub fn new(points: &[Vec3]) -> Self {
        let coords: Vec<[f32; 3]> = points.iter().map(|p| p.to_array()).collect();
        let tree =
            ImmutableKdTree::new_from_slice(&coords).expect("a kd-tree over fewer than 2³² points always builds");
        Self { tree, len: points.len() }
    }

    /// The `count` points nearest to `q` as (index, squared distance), nearest first.
    pub fn nearest(&self, q: Vec3, count: usize) -> Vec<(u32, f32)> {
        let Some(count) = NonZeroUsize::new(count.min(self.len)) else {
            return Vec::new();
        };
        self.tree
            .query(&q.to_array())
            .nearest_n::<SquaredEuclidean<f32>>(count)
            .execute()
            .into_iter()
            .map(|r| (r.item, r.distance))
            .collect()
    }

    /// Every point within distance `radius` of `q` as (index, squared distance), nearest first.
    pub fn within(&self, q: Vec3, radius: f32) -> Vec<(u32, f32)> {
        if self.len == 0 {
            return Vec::new();
        }
        self.tree
            .query(&q.to_array())
            .within::<SquaredEuclidean<f32>>(radius * radius)
            .execute()
            .into_iter()
            .map(|r| (r.item, r.distance))
            .collect()
    }
}

/// The `k` nearest neighbours of every point (k clamped to `n − 1`), queried in parallel.
///
/// Each query asks for `k + 1` points and drops the point itself; if more than `k + 1`
/// points coincide the query may not return the point itself, and then the first `k`
/// (all at distance zero) are kept.
pub fn k_nearest(points: &[Vec3], k: usize) -> Neighbourhoods {
    let n = points.len();
    let k = k.min(n.saturating_sub(1));
    if k == 0 {
        return Neighbourhoods { k, ..Neighbourhoods::default() };
    }
    let index = PointIndex::new(points);
    let mut indices = vec![0u32; n * k];
    let mut sq_dists = vec![0f32; n * k];
    indices.par_chunks_mut(k).zip(sq_dists.par_chunks_mut(k)).enumerate().for_each(|(i, (row, row_dists))| {
        let found = index.nearest(points[i], k + 1);
        let others = found.into_iter().filter(|&(j, _)| j as usize != i).take(k);
        for ((slot, slot_dist), (j, d)) in row.iter_mut().zip(row_dists.iter_mut()).zip(others) {
            *slot = j;
            *slot_dist = d;
        }
    });
    Neighbourhoods { k, indices, sq_dists }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_pcg::Pcg64Mcg;

    fn random_points(n: usize, seed: u64) -> Vec<Vec3> {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        (0..n).map(|_| Vec3::new(rng.random(), rng.random(), rng.random())).collect()
    }

    #[test]
    fn agrees_with_brute_force() {
        let points = random_points(2000, 1);
        let k = 12;
        let nbrs = k_nearest(&points, k);
        assert_eq!(nbrs.k, k);
        assert_eq!(nbrs.len(), points.len());
        for (i, p) in points.iter().enumerate() {
            let mut brute: Vec<(f32, u32)> = (0..points.len() as u32)
                .filter(|&j| j as usize != i)
                .map(|j| (p.distance_squared(points[j as usize]), j))
                .collect();
            brute.sort_by(|a, b| a.0.total_cmp(&b.0));
            let kth = brute[k - 1].0;
            let dists = nbrs.sq_dists_of(i);
            assert!(dists.windows(2).all(|w| w[0] <= w[1]), "not ascending");
            for (&j, &d) in nbrs.of(i).iter().zip(dists) {
                assert_ne!(j as usize, i);
                assert!((d - p.distance_squared(points[j as usize])).abs() <= 1e-6);
                // Same set modulo ties at the k-th distance.
                assert!(d <= kth, "point {i}: neighbour {j} at {d} beyond k-th {kth}");
            }
            let mut set = nbrs.of(i).to_vec();
            set.sort_unstable();
            set.dedup();
            assert_eq!(set.len(), k, "duplicate neighbour indices");
        }
    }

    #[test]
    fn tiny_inputs() {
        assert_eq!(k_nearest(&[], 8).k, 0);
        let one = k_nearest(&[Vec3::ONE], 8);
        assert_eq!((one.k, one.indices.len()), (0, 0));
        let two = k_nearest(&[Vec3::ZERO, Vec3::X], 8);
        assert_eq!((two.k, two.of(0), two.of(1)), (1, &[1u32][..], &[0u32][..]));
        assert_eq!(two.sq_dists, vec![1.0, 1.0]);
    }

    #[test]
    fn coincident_points() {
        let mut points = vec![Vec3::splat(0.5); 500];
        points.extend(random_points(100, 2));
        let nbrs = k_nearest(&points, 8);
        for i in 0..500 {
            assert!(nbrs.of(i).iter().all(|&j| j as usize != i));
            assert!(nbrs.sq_dists_of(i).iter().all(|&d| d == 0.0));
        }
        let index = PointIndex::new(&points);
        assert_eq!(index.within(Vec3::splat(0.5), 0.0).len(), 500);
    }
}

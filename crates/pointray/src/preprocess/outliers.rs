//! Statistical outlier removal, as PCL's `StatisticalOutlierRemoval` and Open3D's
//! `remove_statistical_outlier` do it: a point whose mean distance to its nearest neighbours
//! lies more than a few standard deviations above the cloud's mean is noise (a stray return,
//! dust, a multipath echo). Off by default: the strays that matter most, those that would become
//! giant disks, are dropped anyway ([`super::Strays`]).

use rayon::prelude::*;

use crate::knn::Neighbourhoods;

/// The points to keep: those whose mean neighbour distance is at most the mean over the cloud
/// plus `std_ratio` standard deviations (all, without neighbours).
pub fn statistical_inliers(nbrs: &Neighbourhoods, std_ratio: f32) -> Vec<u32> {
    let n = nbrs.len();
    if nbrs.k == 0 || n == 0 {
        return (0..n as u32).collect();
    }
    let mean_distance = mean_distances(nbrs, n);
    let Ok(limit) = limit(
        |visit| {
            mean_distance.iter().for_each(|&d| visit(d));
            Ok::<_, std::convert::Infallible>(())
        },
        std_ratio,
    );
    (0..n as u32).filter(|&i| mean_distance[i as usize] <= limit).collect()
}

/// The mean distance of each of the first `count` points of `nbrs` to its neighbours (a cloud
/// prepared out of core finds its cells' with their halos).
pub fn mean_distances(nbrs: &Neighbourhoods, count: usize) -> Vec<f64> {
    (0..count)
        .into_par_iter()
        .map(|i| nbrs.sq_dists_of(i).iter().map(|d| f64::from(d.sqrt())).sum::<f64>() / nbrs.k as f64)
        .collect()
}

/// The mean distance above which a point is an outlier: the mean over the cloud plus
/// `std_ratio` standard deviations. `pass` calls its argument with every point's mean distance
/// in the cloud's order; it is called twice (the mean, then the variance), so that a cloud read
/// in passes sums the same numbers in the same order.
pub fn limit<E>(mut pass: impl FnMut(&mut dyn FnMut(f64)) -> Result<(), E>, std_ratio: f32) -> Result<f64, E> {
    let (mut sum, mut n) = (0.0f64, 0usize);
    pass(&mut |d| (sum, n) = (sum + d, n + 1))?;
    let mean = sum / n as f64;
    let mut squares = 0.0f64;
    pass(&mut |d| squares += (d - mean).powi(2))?;
    Ok(mean + f64::from(std_ratio) * (squares / n as f64).sqrt())
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;
    use crate::knn::k_nearest;

    #[test]
    fn isolated_points_are_outliers() {
        let (mut points, _) = crate::preprocess::normals::tests::sphere(5_000, 3);
        let on_sphere = statistical_inliers(&k_nearest(&points, 16), 2.0).len();
        // The filter's nature: the sampling's own tail goes too (2 sigma: a few percent).
        assert!(on_sphere > 4_800 && on_sphere < 5_000, "{on_sphere}");
        points.extend([Vec3::new(1.4, 0.0, 0.0), Vec3::new(0.0, -1.5, 0.0)]);
        let kept = statistical_inliers(&k_nearest(&points, 16), 2.0);
        assert!(kept.iter().all(|&i| i < 5_000), "both isolated points are dropped");
        assert!(kept.len() >= on_sphere - 5, "{}", kept.len());
    }
}

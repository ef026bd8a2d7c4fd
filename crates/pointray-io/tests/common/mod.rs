//! Clouds the out-of-core tests share.

use glam::Vec3;
use pointray::PointCloud;
use pointray::cloud::ScanAttributes;

/// `n` points on a sphere of radius 3 (a golden spiral) with their normals and radii, classes
/// 2, 5 and 6 in turn and intensities.
pub fn classified_sphere(n: usize) -> PointCloud {
    let positions: Vec<Vec3> = (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
            let (r, phi) = ((1.0 - z * z).sqrt(), i as f32 * 2.399_963);
            Vec3::new(r * phi.cos(), r * phi.sin(), z) * 3.0
        })
        .collect();
    PointCloud {
        normals: Some(positions.iter().map(|p| p.normalize()).collect()),
        radii: Some(vec![0.06; n]),
        scan: ScanAttributes {
            classification: Some((0..n).map(|i| [2, 5, 6][i % 3]).collect()),
            intensity: Some((0..n).map(|i| (i * 37 % 1000) as f32).collect()),
            ..ScanAttributes::default()
        },
        positions,
        ..PointCloud::default()
    }
}

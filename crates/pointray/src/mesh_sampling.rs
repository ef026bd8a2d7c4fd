//! Dense point clouds from triangle meshes: points spread uniformly over the surface area,
//! each with the mesh's smooth normal there (and its colour, where the vertices have one), so that scans far denser than the published
//! point sets can be made from the published meshes (`pointray sample`).

use glam::{DVec3, Vec3};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

/// Why a mesh cannot be sampled.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum SampleError {
    #[error("the mesh has no triangle with a positive, finite area")]
    NoArea,
    #[error("triangle {triangle} names vertex {vertex}, but there are {vertices} vertices")]
    BadIndex { triangle: usize, vertex: u32, vertices: usize },
    #[error("{colors} vertex colours for {vertices} vertices")]
    ColorCount { colors: usize, vertices: usize },
}

/// A triangle mesh to sample.
#[derive(Clone, Copy, Debug)]
pub struct SurfaceMesh<'a> {
    pub vertices: &'a [Vec3],
    /// Indices into `vertices`.
    pub triangles: &'a [[u32; 3]],
    /// A colour per vertex, interpolated at each point.
    pub colors: Option<&'a [[f32; 3]]>,
}

/// How a surface is sampled.
#[derive(Clone, Copy, Debug)]
pub struct Sampling {
    pub count: usize,
    /// The same seed gives the same points, whatever the thread count.
    pub seed: u64,
    pub normals: SampleNormals,
}

/// Which normal a sample gets.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SampleNormals {
    /// The vertex normals (area-weighted sums of the faces' normals) interpolated at the
    /// point: smooth shading across edges, as of the surface the mesh approximates. Disks
    /// near a sharp edge then lean off their face.
    #[default]
    Smooth,
    /// The triangle's own normal: disks lie exactly in their faces, shading shows the facets
    /// (for meshes whose edges are real, e.g. CAD models).
    Face,
}

/// Points on a surface, with their normals (unit, on the side the triangles' winding gives).
#[derive(Clone, Debug, Default)]
pub struct SurfaceSamples {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    /// Where the mesh has vertex colours: each point's, interpolated.
    pub colors: Option<Vec<[f32; 3]>>,
    /// The surface's area (of the triangles with a finite area).
    pub area: f64,
    /// Triangles with no area, or a non-finite one (a vertex at NaN or infinity): no points.
    pub empty_triangles: usize,
}

/// Samples per random stream: the streams, not the threads, fix the result, so it is the
/// same for any thread count.
const STREAM: usize = 1 << 16;

/// `count` points uniformly distributed over the mesh's area, from `seed`. A triangle is
/// chosen with probability proportional to its area, then a point in it uniformly
/// (square-root barycentrics), with the normal `normals` asks for (the face's own where smooth
/// normals cancel) and the vertex colours interpolated. Degenerate and non-finite triangles
/// get no samples.
pub fn sample_surface(mesh: &SurfaceMesh, sampling: &Sampling) -> Result<SurfaceSamples, SampleError> {
    let SurfaceMesh { vertices, triangles, colors } = *mesh;
    let Sampling { count, seed, normals } = *sampling;
    if let Some(colors) = colors.filter(|c| c.len() != vertices.len()) {
        return Err(SampleError::ColorCount { colors: colors.len(), vertices: vertices.len() });
    }
    if let Some((triangle, &vertex)) = triangles
        .iter()
        .enumerate()
        .find_map(|(t, tri)| tri.iter().find(|&&v| v as usize >= vertices.len()).map(|v| (t, v)))
    {
        return Err(SampleError::BadIndex { triangle, vertex, vertices: vertices.len() });
    }
    // Twice each triangle's area as a vector along its normal, in f64 for the sums.
    let corners = |t: &[u32; 3]| t.map(|v| vertices[v as usize].as_dvec3());
    let face_vectors: Vec<DVec3> = triangles
        .par_iter()
        .map(|t| {
            let [a, b, c] = corners(t);
            let v = (b - a).cross(c - a);
            if v.is_finite() { v } else { DVec3::ZERO }
        })
        .collect();
    let mut vertex_normals = vec![DVec3::ZERO; vertices.len()];
    for (t, v) in triangles.iter().zip(&face_vectors) {
        for &i in t {
            vertex_normals[i as usize] += *v;
        }
    }
    vertex_normals.iter_mut().for_each(|n| *n = n.normalize_or_zero());
    // Inclusive prefix sums of the areas: a uniform number below the total picks a triangle.
    let cumulative: Vec<f64> = face_vectors
        .iter()
        .scan(0.0, |sum, v| {
            *sum += v.length();
            Some(*sum)
        })
        .collect();
    let total = cumulative.last().copied().unwrap_or(0.0);
    if !(total > 0.0 && total.is_finite()) {
        return Err(SampleError::NoArea);
    }

    let mut positions = vec![Vec3::ZERO; count];
    let kind = normals;
    let mut normals = vec![Vec3::ZERO; count];
    let mut sampled_colors = colors.map(|_| vec![[0.0f32; 3]; count]);
    // Each stream's colours where there are any, else nothing (the same streams either way).
    let color_chunks = match &mut sampled_colors {
        Some(c) => rayon::iter::Either::Left(c.par_chunks_mut(STREAM).map(Some)),
        None => rayon::iter::Either::Right((0..count.div_ceil(STREAM)).into_par_iter().map(|_| None)),
    };
    positions.par_chunks_mut(STREAM).zip(normals.par_chunks_mut(STREAM)).zip(color_chunks).enumerate().for_each(
        |(stream, ((positions, normals), mut stream_colors))| {
            let mut rng = Pcg64Mcg::seed_from_u64(seed ^ (stream as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15));
            for (i, (p, n)) in positions.iter_mut().zip(normals.iter_mut()).enumerate() {
                let pick = rng.random::<f64>() * total;
                // The first triangle whose running sum exceeds the pick; zero-area ones never do.
                let t = cumulative.partition_point(|&s| s <= pick).min(triangles.len() - 1);
                let [a, b, c] = corners(&triangles[t]);
                let s = rng.random::<f64>().sqrt();
                let r = rng.random::<f64>();
                let w = [1.0 - s, s * (1.0 - r), s * r];
                *p = (a * w[0] + b * w[1] + c * w[2]).as_vec3();
                let smooth = || {
                    let [na, nb, nc] = triangles[t].map(|v| vertex_normals[v as usize]);
                    (na * w[0] + nb * w[1] + nc * w[2]).try_normalize()
                };
                let smooth = if kind == SampleNormals::Smooth { smooth() } else { None };
                *n = smooth.unwrap_or_else(|| face_vectors[t].normalize()).as_vec3();
                if let (Some(out), Some(colors)) = (stream_colors.as_deref_mut(), colors) {
                    let [ca, cb, cc] = triangles[t].map(|v| Vec3::from(colors[v as usize]));
                    out[i] = (ca * w[0] as f32 + cb * w[1] as f32 + cc * w[2] as f32).to_array();
                }
            }
        },
    );
    let empty_triangles = face_vectors.iter().filter(|v| **v == DVec3::ZERO).count();
    Ok(SurfaceSamples { positions, normals, colors: sampled_colors, area: total / 2.0, empty_triangles })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(
        v: &[Vec3],
        t: &[[u32; 3]],
        count: usize,
        seed: u64,
        normals: SampleNormals,
    ) -> Result<SurfaceSamples, SampleError> {
        sample_surface(&SurfaceMesh { vertices: v, triangles: t, colors: None }, &Sampling { count, seed, normals })
    }

    /// An octahedron of "radius" 1 (its six vertices on the axes), wound outwards.
    fn octahedron() -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let v = vec![Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z];
        let mut t = Vec::new();
        for (x, y, z) in [(0, 2, 4), (2, 1, 4), (1, 3, 4), (3, 0, 4), (2, 0, 5), (1, 2, 5), (3, 1, 5), (0, 3, 5)] {
            t.push([x, y, z]);
        }
        (v, t)
    }

    #[test]
    fn samples_lie_on_the_surface_uniformly_with_outward_normals() {
        let (v, t) = octahedron();
        let s = sample(&v, &t, 80_000, 1, SampleNormals::Smooth).unwrap();
        // The octahedron |x| + |y| + |z| = 1 has area 4√3.
        assert!((s.area - 4.0 * 3f64.sqrt()).abs() < 1e-9);
        assert!(s.positions.iter().all(|p| (p.abs().element_sum() - 1.0).abs() < 1e-5));
        // Eight equal faces: each octant gets 1/8 of the points (binomial sd ≈ 94).
        let mut octants = [0usize; 8];
        for p in &s.positions {
            octants[usize::from(p.x < 0.0) | usize::from(p.y < 0.0) << 1 | usize::from(p.z < 0.0) << 2] += 1;
        }
        assert!(octants.iter().all(|&n| n.abs_diff(10_000) < 500), "{octants:?}");
        // Within the face x, y, z > 0, the points with x > 1 − 1/√2 fill the corner triangle
        // at +X scaled by 1/√2, which has half the face's area: half the points must be there.
        let face: Vec<&Vec3> = s.positions.iter().filter(|p| p.x > 0.0 && p.y > 0.0 && p.z > 0.0).collect();
        let near_x = face.iter().filter(|p| p.x > 1.0 - 0.5f32.sqrt()).count() as f64 / face.len() as f64;
        assert!((near_x - 0.5).abs() < 0.02, "{near_x}");
        // Smooth normals point outwards everywhere and are unit.
        assert!(s.normals.iter().zip(&s.positions).all(|(n, p)| n.is_normalized() && n.dot(*p) > 0.0));
        // Face normals are the octant's diagonal, and the points the same.
        let f = sample(&v, &t, 80_000, 1, SampleNormals::Face).unwrap();
        assert_eq!(f.positions, s.positions);
        let diagonal = |n: Vec3, p: Vec3| (n - p.signum() / 3f32.sqrt()).length() < 1e-6;
        assert!(f.normals.iter().zip(&f.positions).all(|(n, p)| diagonal(*n, *p)));
    }

    #[test]
    fn the_same_seed_gives_the_same_points_for_any_thread_count() {
        let (v, t) = octahedron();
        let run = |threads: usize, seed: u64| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| sample(&v, &t, 3 * STREAM + 17, seed, SampleNormals::Smooth).unwrap().positions)
        };
        assert_eq!(run(1, 7), run(3, 7));
        assert_ne!(run(2, 7), run(2, 8));
    }

    #[test]
    fn vertex_colours_are_interpolated_and_change_no_point() {
        let (v, t) = octahedron();
        let colors: Vec<[f32; 3]> = v.iter().map(|p| (p.abs()).to_array()).collect();
        let sampling = Sampling { count: 5000, seed: 4, normals: SampleNormals::Smooth };
        let plain = sample_surface(&SurfaceMesh { vertices: &v, triangles: &t, colors: None }, &sampling).unwrap();
        let mesh = SurfaceMesh { vertices: &v, triangles: &t, colors: Some(&colors) };
        let coloured = sample_surface(&mesh, &sampling).unwrap();
        assert_eq!((plain.positions, plain.colors), (coloured.positions.clone(), None));
        // On |x| + |y| + |z| = 1 the corners' colours (|x|, |y|, |z|) interpolate to the point's own.
        for (p, c) in coloured.positions.iter().zip(coloured.colors.unwrap()) {
            assert!((Vec3::from(c) - p.abs()).length() < 1e-5, "{p} {c:?}");
        }
        let short = SurfaceMesh { colors: Some(&colors[..2]), ..mesh };
        assert_eq!(sample_surface(&short, &sampling).unwrap_err(), SampleError::ColorCount { colors: 2, vertices: 6 });
    }

    #[test]
    fn degenerate_meshes_are_refused_and_degenerate_triangles_skipped() {
        let (mut v, mut t) = octahedron();
        assert_eq!(sample(&v, &[], 10, 1, SampleNormals::Face).unwrap_err(), SampleError::NoArea);
        assert_eq!(sample(&v, &[[0, 0, 1], [1, 1, 1]], 10, 1, SampleNormals::Face).unwrap_err(), SampleError::NoArea);
        assert_eq!(
            sample(&v, &[[0, 1, 6]], 10, 1, SampleNormals::Face).unwrap_err(),
            SampleError::BadIndex { triangle: 0, vertex: 6, vertices: 6 }
        );
        // A triangle through a NaN vertex and a sliver get nothing; the rest is sampled.
        v.push(Vec3::NAN);
        t.push([0, 2, 6]);
        t.push([0, 0, 2]);
        let s = sample(&v, &t, 1000, 3, SampleNormals::Face).unwrap();
        assert_eq!(s.empty_triangles, 2);
        assert!(s.positions.iter().all(|p| p.is_finite() && (p.abs().element_sum() - 1.0).abs() < 1e-5));
        assert_eq!(sample(&v, &t, 0, 3, SampleNormals::Face).unwrap().positions.len(), 0);
    }
}

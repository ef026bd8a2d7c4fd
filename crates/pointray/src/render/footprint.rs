//! A camera ray through the footprint prefilter (`splat::footprint`): its pixel's layers
//! shaded once each, front to back, and blended by their coverage with what lies behind.

use arrayvec::ArrayVec;
use glam::Vec3;

use super::Tracer;
use crate::accel::Accel;
use crate::material::{Material, Phong};
use crate::math::{Ray, RayCone};
use crate::render::Integrator;
use crate::shading::Light;
use crate::splat::footprint::{Footprint, Layer, OPAQUE, ShadowBeam, shadow_origin};
use crate::splat::scheme::SurfaceHit;

/// Layers shaded at most; light past them is what lies behind.
const MAX_LAYERS: usize = 16;

impl<A: Accel> Tracer<'_, A> {
    /// The radiance of `ray`'s pixel footprint, or `None` where a layer is not of a Phong
    /// material (mirrors and glass are traced as rays).
    #[inline(never)]
    pub(super) fn footprint_radiance(&mut self, ray: &Ray) -> Option<Vec3> {
        let config = self.config;
        let ground = config.ground.as_ref().and_then(|g| g.intersect(ray, f32::INFINITY).map(|hit| (g, hit)));
        let t_max = ground.as_ref().map_or(f32::INFINITY, |(_, hit)| hit.t);
        let mut footprint = Footprint::new(self.accel, ray, t_max);
        footprint.gather(self.accel, 1.0, &mut self.stats.traversal);
        let layers = self.phong_layers(&footprint)?;
        self.stats.rays += 1;
        self.stats.primary_hits += u64::from(!layers.is_empty());
        let mut radiance = Vec3::ZERO;
        let mut transmit = 1.0;
        for (i, (layer, phong)) in layers.iter().enumerate() {
            let weight = transmit * layer.coverage;
            let (hit, agreement) = layer_hit(ray, &footprint, layer);
            self.record_first(&hit, weight, layer.color, layer.t, i == 0);
            radiance += weight * self.shade_layer(ray, &footprint, layer, &hit, phong, agreement);
            transmit *= 1.0 - layer.coverage;
        }
        let behind = match ground {
            Some((plane, hit)) => {
                // The ground covers what the layers leave.
                self.record_first(&hit, transmit, Vec3::from(hit.color), hit.t, layers.is_empty());
                self.shade(ray, &hit, plane.material, 0, false)
            }
            None => self.missed(ray, 0, 0.0),
        };
        Some(radiance + transmit * behind)
    }

    /// The layers up to the first opaque one, each with its material, or `None` where one is
    /// not Phong.
    fn phong_layers(&self, footprint: &Footprint) -> Option<ArrayVec<(Layer, Phong), MAX_LAYERS>> {
        let materials = &self.config.materials;
        let mut layers = ArrayVec::new();
        let mut transmit = 1.0;
        for layer in footprint.layers().take(MAX_LAYERS) {
            let index = usize::from(self.accel.splat(layer.index).material());
            let Some(Material::Phong(phong)) = materials.get(index).or(materials.first()).copied() else {
                return None;
            };
            transmit *= 1.0 - layer.coverage;
            layers.push((layer, phong));
            if transmit < OPAQUE {
                break;
            }
        }
        Some(layers)
    }

    /// Adds a share `weight` of the pixel seeing `hit` (albedo `albedo`) to the film's first
    /// hits, its depth `t` too if it is the `front`.
    fn record_first(&mut self, hit: &SurfaceHit, weight: f32, albedo: Vec3, t: f32, front: bool) {
        if !self.config.first_hit_aovs {
            return;
        }
        let first = &mut *self.first;
        (first.normal, first.albedo, first.covered) =
            (first.normal + weight * hit.normal, first.albedo + weight * albedo, first.covered + weight);
        if front {
            (first.depth, first.hits) = (first.depth + t, first.hits + 1);
        }
    }

    /// What `layer` sends back along `ray`, each light seen through its shadow beam's share:
    /// Phong, its ambient term from the mean albedo, its Lambert term [`lambert`]'s, its
    /// highlight from the mean normal widened by the normals' spread (Toksvig).
    fn shade_layer(
        &mut self,
        ray: &Ray,
        footprint: &Footprint,
        layer: &Layer,
        hit: &SurfaceHit,
        phong: &Phong,
        agreement: f32,
    ) -> Vec3 {
        let config = self.config;
        if config.integrator == Integrator::EyeLight {
            // The mean of |n·d| over the pixel, as many rays would see it.
            return layer.color * layer.normal.dot(ray.dir).abs();
        }
        let phong = phong.rough(agreement);
        let mut color = self.ambient(&phong, hit);
        for light in &config.lights {
            let (to_light, _, irradiance) = light.towards(hit.position);
            let Some(lambert) = lambert(footprint, layer, to_light) else { continue };
            let seen = if config.shadows { self.layer_visibility(footprint, layer, light) } else { 1.0 };
            if seen > 0.0 {
                let diffuse = lambert * (irradiance * (1.0 - phong.ambient));
                color += seen * (diffuse + phong.glossy(hit.normal, -ray.dir, to_light, irradiance));
            }
        }
        color
    }

    /// The share of `layer` that sees `light`: the share of its sample points whose shadow
    /// rays nothing blocks, found by one gather along the light ([`ShadowBeam`]). Each ray
    /// leaves the layer where its sample meets it, [`SHADOW_LIFT`] of `shadow_offset` disk
    /// radii off the surface, and ignores what lies within a disk radius, as a shadow ray from
    /// a disk does. The gather leaves out pieces facing away, as the camera's does: the layer's
    /// own surface, which faces the light, and the far sides of occluders, whose near sides
    /// block; but so also the back of a sheet scanned from one side (a roof seen from the
    /// ground below it). Backs counted cost the Happy Buddha 1.5 to 3 dB (`docs/RESULTS.md`).
    fn layer_visibility(&mut self, footprint: &Footprint, layer: &Layer, light: &Light) -> f32 {
        let config = self.config;
        let origin = shadow_origin(footprint, layer);
        let u = if light.is_area() { [self.rng.next(), self.rng.next()] } else { [0.5; 2] };
        let (direction, distance) = light.shadow_target(origin, u);
        self.stats.rays += 1;
        self.stats.shadow_rays += 1;
        let axis = Ray::new(origin, direction, RayCone::default());
        if config.ground.is_some_and(|ground| ground.blocks(&axis, distance)) {
            return 0.0;
        }
        let reach = config.scheme.self_hit_radii();
        let lift = SHADOW_LIFT * config.shadow_offset * reach;
        let Some(mut beam) = ShadowBeam::new(footprint, layer, direction, distance, lift, reach) else {
            return 1.0;
        };
        beam.gather(self.accel, 1.0, &mut self.stats.traversal);
        1.0 - beam.blocked()
    }
}

/// The mean over `layer`'s pieces, by coverage, of albedo × agreement × max(0, n·l), or none
/// where no piece faces the light: each piece's own cosine, since near the terminator, where
/// some normals under the pixel face the light and some away, the mean normal's cosine is less
/// than the mean cosine. Against the mean normal's the dragon at 16 diagonals, three views and
/// the Happy Buddha from two, came 0.2 / 0.9 / 0.3 / 0.3 / 0.2 dB closer to 256 rays a pixel, and
/// lighting layers whose mean normal faces away 0.05 / 0.7 / 0.4 / 0.1 / 0.1 more; each piece's
/// highlight as well, 0.15 dB at most (`docs/RESULTS.md`).
fn lambert(footprint: &Footprint, layer: &Layer, to_light: Vec3) -> Option<Vec3> {
    let (mut sum, mut weight, mut lit) = (Vec3::ZERO, 0.0, false);
    for p in &footprint.pieces()[layer.pieces.clone()] {
        let cos = p.normal.dot(to_light);
        lit |= cos > 0.0;
        sum += (p.coverage * p.agreement * cos.max(0.0)) * p.color;
        weight += p.coverage;
    }
    (lit && weight > 0.0).then(|| sum / weight)
}

/// A layer's shadow rays start this share of `shadow_offset` disk radii off its surface (a
/// shadow ray from a disk: all of it). The dragon at 16 diagonals from three views and the
/// Happy Buddha from two, against 256 rays a pixel: ¼, ½, ¾ and 1 gave 39.2 / 39.1 / 38.7 /
/// 30.4 / 29.5, 39.7 / 39.3 / 39.1 / 31.1 / 30.2, 39.8 / 39.5 / 38.1 / 31.4 / 31.0 and 39.7 /
/// 39.5 / 36.7 / 31.4 / 31.4 dB: a representative's disk, wider than its disks, lifts too far
/// (`docs/RESULTS.md`).
const SHADOW_LIFT: f32 = 0.5;

/// The hit a layer shades as: at its mean depth on the beam's axis, with its mean albedo and
/// its mean normal made unit; and the normals' agreement (the mean's length), which it returns.
fn layer_hit(ray: &Ray, footprint: &Footprint, layer: &Layer) -> (SurfaceHit, f32) {
    let length = layer.normal.length();
    let (normal, agreement) = if length > 0.0 { (layer.normal / length, length.min(1.0)) } else { (-ray.dir, 0.0) };
    let hit = SurfaceHit {
        t: layer.t,
        position: ray.origin + layer.t * ray.dir,
        normal,
        color: layer.color.to_array(),
        radius: footprint.beam.radius(layer.t),
        splat: layer.index,
        blended: layer.pieces.len() as u32,
    };
    (hit, agreement)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::{Bvh, BvhParams, TraversalStats};
    use crate::splat::{Splat, pack_color};

    /// Disks under a beam, every other column tilted 30° towards a grazing light and the rest
    /// 30° away, past the terminator: shaded as many rays would, half at cos 0.83 and half
    /// unlit, 0.41 of the albedo; the mean normal's cosine would give 0.38 (with equal shares).
    #[test]
    fn lambert_is_the_mean_of_each_pieces_clamped_cosine() {
        let (toward, away) = (Vec3::new(0.5, 0.0, 0.866), Vec3::new(-0.5, 0.0, 0.866));
        let disks: Vec<Splat> = (0..400)
            .map(|i| Splat {
                center: Vec3::new((i % 20) as f32 / 20.0 - 0.5, (i / 20) as f32 / 20.0 - 0.5, 0.0),
                radius: 0.06,
                normal: if i % 2 == 0 { toward } else { away },
                color: pack_color([0.5; 3]),
            })
            .collect();
        let bvh = Bvh::build(disks, &BvhParams::standard());
        let ray = Ray::new(Vec3::new(0.0, 0.0, 3.0), -Vec3::Z, RayCone { width0: 0.4, spread: 0.0 });
        let mut footprint = Footprint::new(&bvh, &ray, f32::INFINITY);
        footprint.gather(&bvh, 0.0, &mut TraversalStats::default());
        let layer = footprint.layers().next().expect("the disks");
        let light = Vec3::new(0.9, 0.0, 0.436).normalize();
        let lit = lambert(&footprint, &layer, light).expect("half the disks face the light").x / layer.color.x;
        // The share of the layer tilted towards the light, from its mean normal (about half).
        let toward_share = 0.5 + layer.normal.x;
        assert!((toward_share - 0.5).abs() < 0.05, "{toward_share}");
        let many_rays = toward_share * toward.dot(light);
        let mean_normal = layer.normal.dot(light);
        assert!((lit - many_rays).abs() < 0.01, "{lit} against {many_rays}");
        assert!(lit > mean_normal + 0.02, "{lit} against the mean normal's {mean_normal}");
        assert!(lambert(&footprint, &layer, -Vec3::Z).is_none(), "a light from below meets no piece's face");
    }
}

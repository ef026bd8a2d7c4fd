//! The accelerators the command line builds, behind one enum: `render` and `bench` pick one at
//! run time, and the render loop is monomorphised for each.

use pointray::accel::{Accel, BruteForce, Bvh, BvhParams, KdTree, KdTreeParams, NodeBounds, backfacing_fraction};
use pointray::camera::Camera;
use pointray::film::Film;
use pointray::render::{RenderConfig, render, render_into};
use pointray::splat::{DiskShape, Splat};
use pointray::stats::RenderStats;

use crate::args::AccelArg;

/// The accelerators the CLI can build; the render loop is monomorphised for each.
pub enum AnyAccel {
    Bvh(Bvh),
    KdTree(KdTree),
    Brute(BruteForce),
}

impl AnyAccel {
    /// The accelerator over `splats`, its bounds holding the disks of `shape`.
    pub fn build(kind: AccelArg, splats: Vec<Splat>, node_bounds: NodeBounds, shape: DiskShape) -> Self {
        match kind {
            AccelArg::Bvh => {
                AnyAccel::Bvh(Bvh::build(splats, &BvhParams { node_bounds, shape, ..BvhParams::standard() }))
            }
            AccelArg::Kdtree => {
                AnyAccel::KdTree(KdTree::build(splats, &KdTreeParams { shape, ..KdTreeParams::standard() }))
            }
            AccelArg::Brute => AnyAccel::Brute(BruteForce::new(splats)),
        }
    }

    pub fn memory_bytes(&self) -> usize {
        match self {
            AnyAccel::Bvh(a) => a.memory_bytes(),
            AnyAccel::KdTree(a) => a.memory_bytes(),
            AnyAccel::Brute(a) => a.memory_bytes(),
        }
    }

    pub fn name(&self) -> &'static str {
        match self {
            AnyAccel::Bvh(a) => a.name(),
            AnyAccel::KdTree(a) => a.name(),
            AnyAccel::Brute(a) => a.name(),
        }
    }

    pub fn bounds(&self) -> pointray::math::Aabb {
        match self {
            AnyAccel::Bvh(a) => a.bounds(),
            AnyAccel::KdTree(a) => a.bounds(),
            AnyAccel::Brute(a) => a.bounds(),
        }
    }

    pub fn backfacing_fraction(&self) -> Option<f64> {
        match self {
            AnyAccel::Bvh(a) => backfacing_fraction(a, CULL_CHECK_RAYS, 0),
            // Only the BVH culls.
            AnyAccel::KdTree(_) | AnyAccel::Brute(_) => None,
        }
    }

    /// Nodes, the nodes that test spheres, and bytes per node (none for brute force).
    pub fn node_summary(&self) -> (usize, usize, usize) {
        match self {
            AnyAccel::Bvh(a) => (a.node_count(), a.sphere_node_count(), Bvh::NODE_BYTES),
            AnyAccel::KdTree(a) => (a.node_count(), 0, KdTree::NODE_BYTES),
            AnyAccel::Brute(_) => (0, 0, 0),
        }
    }

    pub fn render(
        &self,
        camera: &Camera,
        config: &RenderConfig,
        progress: &(dyn Fn(u64) + Sync),
    ) -> (Film, RenderStats) {
        match self {
            AnyAccel::Bvh(a) => render(a, camera, config, progress),
            AnyAccel::KdTree(a) => render(a, camera, config, progress),
            AnyAccel::Brute(a) => render(a, camera, config, progress),
        }
    }

    /// `pointray::render::render_into` on whichever accelerator this is.
    pub fn render_into(
        &self,
        camera: &Camera,
        config: &RenderConfig,
        film: &mut Film,
        progress: &(dyn Fn(u64) + Sync),
    ) -> RenderStats {
        match self {
            AnyAccel::Bvh(a) => render_into(a, camera, config, film, progress),
            AnyAccel::KdTree(a) => render_into(a, camera, config, film, progress),
            AnyAccel::Brute(a) => render_into(a, camera, config, film, progress),
        }
    }
}

/// Rays of the `--cull auto` check (a few milliseconds on the BVH).
const CULL_CHECK_RAYS: usize = 4096;

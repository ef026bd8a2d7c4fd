//! Front-to-back traversal: test a node's four child boxes at once, go on with the nearest
//! child hit, and keep the others on a stack with their entry distances, so that they can be
//! culled later when the visitor's `t_max` has shrunk below them.

use glam::Vec4;

use super::{Bvh, LEAF, Node, SplatPacket, WIDTH, leaf_packets};
use crate::accel::{SplatVisitor, TraversalStats};
use crate::math::Ray;

/// The ray in the form the four-box slab test wants: per axis the origin and inverse
/// direction splatted to four lanes, and per axis which of a node's planes is near (the
/// minimum, or the maximum when the axis runs backwards) and which is far.
struct SlabRay {
    origin: [Vec4; 3],
    dir: [Vec4; 3],
    inv_dir: [Vec4; 3],
    near_plane: [usize; 3],
    far_plane: [usize; 3],
}

impl SlabRay {
    fn new(ray: &Ray) -> Self {
        Self {
            origin: std::array::from_fn(|k| Vec4::splat(ray.origin[k])),
            dir: std::array::from_fn(|k| Vec4::splat(ray.dir[k])),
            inv_dir: std::array::from_fn(|k| Vec4::splat(ray.inv_dir[k])),
            near_plane: std::array::from_fn(|k| if ray.inv_dir[k] < 0.0 { k + 3 } else { k }),
            far_plane: std::array::from_fn(|k| if ray.inv_dir[k] < 0.0 { k } else { k + 3 }),
        }
    }

    /// Entry distances of the four children of `node` within `[t0, t1]`, and a bit mask of
    /// the children the ray enters.
    #[inline(always)]
    fn entries(&self, node: &Node, t0: f32, t1: f32) -> (Vec4, u32) {
        let near = |k: usize| (node.planes[self.near_plane[k]] - self.origin[k]) * self.inv_dir[k];
        let far = |k: usize| (node.planes[self.far_plane[k]] - self.origin[k]) * self.inv_dir[k];
        let near = near(0).max(near(1)).max(near(2)).max(Vec4::splat(t0));
        let far = far(0).min(far(1)).min(far(2)).min(Vec4::splat(t1));
        (near, near.cmple(far).bitmask() & node.used)
    }

    /// The lanes of `packet` whose disk the ray may cross in `[t0, t1]`. The arithmetic is the
    /// scalar test's (`splat::oriented_disk::intersect`) lane by lane, in the same order, with
    /// a little more slack: a pre-filter that never rejects a disk the exact test accepts.
    #[inline(always)]
    fn packet_candidates(&self, packet: &SplatPacket, t0: f32, t1: f32) -> u32 {
        let dot = |a: &[Vec4; 3], b: &[Vec4; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let den = dot(&self.dir, &packet.normal);
        let to_center: [Vec4; 3] = std::array::from_fn(|k| packet.center[k] - self.origin[k]);
        let num = dot(&to_center, &packet.normal);
        let negative = den.cmplt(Vec4::ZERO);
        let num_s = Vec4::select(negative, -num, num);
        let den_a = den.abs();
        const SLACK: f32 = 1.0 / 16384.0;
        let in_range = num_s.cmpge(Vec4::splat(t0 * (1.0 - SLACK)) * den_a)
            & num_s.cmple(Vec4::splat(t1 * (1.0 + SLACK)) * den_a)
            & den_a.cmpgt(Vec4::ZERO);
        let q: [Vec4; 3] = std::array::from_fn(|k| self.dir[k] * num - to_center[k] * den);
        let q2 = dot(&q, &q);
        let r2_den2 = packet.radius * packet.radius * den * den * (1.0 + SLACK);
        (in_range & q2.cmplt(r2_den2)).bitmask()
    }
}

/// Widens the visitor's `t_max` for culling by a few ulps: a box's entry distance and the hit
/// distance of a disk lying on the box's face are rounded differently, and a box must never be
/// culled against a hit it may tie with (accelerators must find the same nearest disk).
#[inline(always)]
fn cull_limit(t_max: f32) -> f32 {
    t_max * (1.0 + 1.0 / 65536.0)
}

thread_local! {
    /// Each thread's traversal stack, reused from ray to ray: a fresh array per ray would cost
    /// a memset of the whole stack every time.
    static STACK: std::cell::RefCell<Vec<(u32, f32)>> = const { std::cell::RefCell::new(Vec::new()) };
}

pub(super) fn traverse<V: SplatVisitor>(bvh: &Bvh, ray: &Ray, visitor: &mut V, stats: &mut TraversalStats) {
    if bvh.nodes.is_empty() {
        return;
    }
    // Each level pushes at most WIDTH − 1 entries.
    let need = (WIDTH - 1) * bvh.depth + 1;
    STACK.with(|cell| match cell.try_borrow_mut() {
        Ok(mut stack) => {
            if stack.len() < need {
                stack.resize(need, (0, 0.0));
            }
            traverse_with(bvh, ray, visitor, stats, &mut stack);
        }
        // Re-entered from inside a visitor (a traversal that starts another): its own stack.
        Err(_) => traverse_with(bvh, ray, visitor, stats, &mut vec![(0, 0.0); need]),
    });
}

/// The traversal proper, with `stack` large enough for the tree: entries are
/// (child reference, entry distance).
#[inline(always)]
fn traverse_with<V: SplatVisitor>(
    bvh: &Bvh,
    ray: &Ray,
    visitor: &mut V,
    stats: &mut TraversalStats,
    stack: &mut [(u32, f32)],
) {
    let slab = SlabRay::new(ray);
    let mut sp = 0;
    let mut current = (0u32, ray.t_min);
    loop {
        let (child, entry) = current;
        if entry <= cull_limit(visitor.t_max()) {
            if child & LEAF != 0 {
                for packet in &bvh.packets[leaf_packets(child)] {
                    stats.splat_tests += u64::from(packet.count);
                    let mut lanes = slab.packet_candidates(packet, ray.t_min, visitor.t_max());
                    while lanes != 0 {
                        let i = packet.first as usize + lanes.trailing_zeros() as usize;
                        lanes &= lanes - 1;
                        visitor.visit(ray, &bvh.splats[i], i as u32);
                    }
                }
                if visitor.done() {
                    return;
                }
            } else {
                let node = &bvh.nodes[child as usize];
                stats.nodes_visited += 1;
                let (t, mut mask) = slab.entries(node, ray.t_min, cull_limit(visitor.t_max()));
                if mask.is_power_of_two() {
                    // One child hit (the common case deep in the tree): no stack traffic.
                    let i = mask.trailing_zeros() as usize;
                    current = (node.child[i], t[i]);
                    continue;
                }
                if mask != 0 {
                    // Push the children hit, keeping the nearest at `base`, then move it to the
                    // top and take it: the rest of the stack needs no order (each entry is
                    // culled by its own distance when popped).
                    let base = sp;
                    while mask != 0 {
                        let i = mask.trailing_zeros() as usize;
                        mask &= mask - 1;
                        stack[sp] = (node.child[i], t[i]);
                        if stack[sp].1 < stack[base].1 {
                            stack.swap(sp, base);
                        }
                        sp += 1;
                    }
                    stack.swap(base, sp - 1);
                    sp -= 1;
                    current = stack[sp];
                    continue;
                }
            }
        }
        if sp == 0 {
            return;
        }
        sp -= 1;
        current = stack[sp];
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;
    use rand::{RngExt, SeedableRng};

    use super::*;
    use crate::math::RayCone;
    use crate::splat::{Splat, oriented_disk};

    /// The SIMD pre-filter may pass disks the exact test rejects, never the other way round:
    /// otherwise the BVH would miss hits that brute force finds.
    #[test]
    fn packet_prefilter_never_rejects_an_exact_hit() {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(5);
        let mut v =
            |lo: f32, hi: f32| Vec3::new(rng.random_range(lo..hi), rng.random_range(lo..hi), rng.random_range(lo..hi));
        let (mut hits, mut rejected) = (0, 0);
        for _ in 0..20_000 {
            let splats: Vec<Splat> = (0..4)
                .map(|_| Splat {
                    center: v(-1.0, 1.0),
                    radius: v(0.05, 1.0).x,
                    normal: v(-1.0, 1.0).normalize(),
                    color: 0,
                })
                .collect();
            let packet = SplatPacket::new(&splats, 0);
            let origin = v(-3.0, 3.0);
            let ray = Ray::new(origin, v(-1.0, 1.0) - origin, RayCone::default()).with_t_min(v(0.0, 0.5).x);
            let t_max = if v(0.0, 1.0).x < 0.5 { f32::INFINITY } else { v(0.5, 6.0).x };
            let candidates = SlabRay::new(&ray).packet_candidates(&packet, ray.t_min, t_max);
            for (lane, s) in splats.iter().enumerate() {
                let exact = oriented_disk::intersect(&ray, s, t_max).is_some();
                let passed = candidates & (1 << lane) != 0;
                assert!(!exact || passed, "lane {lane} of {splats:?} rejected for {ray:?} up to {t_max}");
                hits += usize::from(exact);
                rejected += usize::from(!passed);
            }
        }
        assert!(hits > 1_000 && rejected > 10_000, "the test must see both: {hits} hits, {rejected} rejections");
    }
}

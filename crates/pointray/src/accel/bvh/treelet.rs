//! Treelets: the tree cut into its top and the subtrees below it of at most [`TREELET_SPLATS`]
//! splats, each laid out contiguously (its nodes after the top's, its blocks in leaf order), so
//! that a scene file can check each on its own, the first time a walk enters it, and a view
//! reads only the treelets it enters (`docs/prs.md`).
//!
//! In memory the top's nodes name their treelets' roots as any child. Stored, they name the
//! treelet instead ([`treelet_ref`], a node index past every node), and a walk that meets one
//! asks [`Bvh::enter`] for the root, the one place the check happens: past the bounds check of
//! `nodes[k]` in the level-of-detail loop, which stored trees always take, so that the
//! full-detail loop, which only trees in memory take, is what it was.

use std::sync::OnceLock;

use super::lod::{Lod, NodeAggregate, NodeLod, node_ranges};
use super::{Bvh, LEAF, MAX_DEPTH, Node, SLOTS, WIDTH, leaf_blocks, leaf_size};
use crate::accel::block::SplatBlock;

/// The most splats a treelet holds: at 176 bytes a block and 560 a node, at most some 150 kB of
/// a scene file (30 million points: 31,900 treelets of 940 splats on average). Smaller than a pixel in a far view of a large scan, so that level of detail stops
/// above most of them and the view reads the top alone.
pub(crate) const TREELET_SPLATS: usize = 4096;

/// Where treelet references start: past any node index (a BVH has fewer nodes than splats,
/// at most 2²⁸), below [`LEAF`].
const TREELET_BASE: u32 = 1 << 30;

/// The child reference of treelet `t` in a stored top node.
pub(super) fn treelet_ref(t: usize) -> u32 {
    TREELET_BASE + t as u32
}

/// A subtree below the top.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct Treelet {
    /// Its root: a node index or a leaf reference, as an in-memory parent names it.
    pub(crate) root: u32,
    /// The top node holding it, and the slot.
    pub(crate) parent: u32,
    pub(crate) slot: u32,
    /// Its nodes (none for a lone leaf) and its blocks: start, end.
    pub(crate) nodes: [u32; 2],
    pub(crate) blocks: [u32; 2],
    /// CRC-32 of its bytes as a scene file stores them: its nodes', spheres', representatives',
    /// aggregates' and blocks', in that order (0 until stored).
    pub(crate) crc: u32,
}

impl Treelet {
    pub(crate) fn node_range(&self) -> std::ops::Range<usize> {
        self.nodes[0] as usize..self.nodes[1] as usize
    }

    pub(crate) fn block_range(&self) -> std::ops::Range<usize> {
        self.blocks[0] as usize..self.blocks[1] as usize
    }
}

/// The arrays of a built tree, reordered so that the top's nodes come first and each treelet's
/// after them in one run; the treelets, and how many nodes the top has.
pub(super) struct Partition {
    pub(super) nodes: Vec<Node>,
    pub(super) lod: Vec<NodeLod>,
    pub(super) representatives: Vec<SplatBlock>,
    pub(super) aggregates: Vec<NodeAggregate>,
    pub(super) treelets: Vec<Treelet>,
    pub(super) top: usize,
}

/// Cuts the tree (children stored after their parents, depth first, as the build leaves them)
/// into its top, every node above more than [`TREELET_SPLATS`] splats and the first `always`
/// (a whole tree's root; a chunked tree's octree nodes, `super::chunk`; none for a chunk's own,
/// `super::streamed`), and the treelets below. A root below the top is a treelet's, with no
/// parent yet (`u32::MAX`).
pub(super) fn partition(nodes: Vec<Node>, lod: Lod, always: usize) -> Partition {
    let Lod { lod, representatives, aggregates, .. } = lod;
    let n = nodes.len();
    // Splats and nodes below each node, children first.
    let (mut splats, mut size) = (vec![0usize; n], vec![1usize; n]);
    for k in (0..n).rev() {
        for i in used(&nodes[k]) {
            let c = nodes[k].child[i];
            if c & LEAF != 0 {
                splats[k] += leaf_size(c);
            } else {
                splats[k] += splats[c as usize];
                size[k] += size[c as usize];
            }
        }
    }
    let top: Vec<bool> = (0..n).map(|k| k < always || splats[k] > TREELET_SPLATS).collect();
    // Depth first, the top's nodes are those of a subtree about the root, and every treelet is
    // a run of the rest.
    let order: Vec<usize> = (0..n).filter(|&k| top[k]).chain((0..n).filter(|&k| !top[k])).collect();
    let mut new_index = vec![0u32; n];
    for (new, &old) in order.iter().enumerate() {
        new_index[old] = new as u32;
    }
    let blocks = node_ranges(&nodes);
    let remap = |c: u32| if c & LEAF != 0 { c } else { new_index[c as usize] };
    let mut treelets = Vec::new();
    for (parent, &old) in order.iter().enumerate().take_while(|&(_, &old)| top[old]) {
        for i in used(&nodes[old]) {
            let c = nodes[old].child[i];
            if c & LEAF == 0 && top[c as usize] {
                continue;
            }
            let (first, count, range) = if c & LEAF != 0 {
                (0, 0, leaf_blocks(c))
            } else {
                (new_index[c as usize], size[c as usize], blocks[c as usize].clone())
            };
            treelets.push(Treelet {
                root: remap(c),
                parent: parent as u32,
                slot: i as u32,
                nodes: [first, first + count as u32],
                blocks: [range.start as u32, range.end as u32],
                crc: 0,
            });
        }
    }
    if n > 0 && !top[0] {
        let range = blocks[0].clone();
        treelets.push(Treelet {
            root: 0,
            parent: u32::MAX,
            slot: u32::MAX,
            nodes: [0, n as u32],
            blocks: [range.start as u32, range.end as u32],
            crc: 0,
        });
    }
    let top_count = top.iter().filter(|&&t| t).count();
    place_in_order(&mut treelets, top_count);
    let permute = |k: usize| order[k];
    let nodes: Vec<Node> = (0..n)
        .map(|k| {
            let mut node = nodes[permute(k)];
            for i in used(&node) {
                node.child[i] = remap(node.child[i]);
            }
            node
        })
        .collect();
    Partition {
        nodes,
        lod: (0..n).map(|k| lod[permute(k)]).collect(),
        representatives: (0..n).map(|k| representatives[permute(k)]).collect(),
        aggregates: (0..n).map(|k| aggregates[permute(k)]).collect(),
        treelets,
        top: top_count,
    }
}

/// Orders the treelets as their runs lie, depth first (by first block: every treelet has one),
/// and gives each lone leaf the empty run of nodes where it stands.
fn place_in_order(treelets: &mut [Treelet], top: usize) {
    treelets.sort_unstable_by_key(|t| t.blocks[0]);
    let mut next = top as u32;
    for t in treelets {
        if t.root & LEAF != 0 {
            t.nodes = [next; 2];
        }
        debug_assert_eq!(t.nodes[0], next, "a treelet's nodes follow the one before");
        next = t.nodes[1];
    }
}

/// The slots of `node` in use.
fn used(node: &Node) -> impl Iterator<Item = usize> + use<> {
    let used = node.used & SLOTS;
    (0..WIDTH).filter(move |&i| used & (1 << i) != 0)
}

/// What a stored tree keeps of its treelets' checks: each checked once, when first entered.
pub(crate) struct Lazy {
    /// Whether each treelet proved whole.
    whole: Box<[OnceLock<bool>]>,
    /// The depth of each treelet's root (the root's 1).
    depth: Box<[u8]>,
    /// The first damage found.
    damage: OnceLock<String>,
}

impl Lazy {
    pub(crate) fn damage(&self) -> Option<&str> {
        self.damage.get().map(String::as_str)
    }

    /// How many treelets were checked so far.
    #[cfg(test)]
    pub(crate) fn checked(&self) -> usize {
        self.whole.iter().filter(|w| w.get().is_some()).count()
    }
}

impl Bvh {
    /// The root of treelet reference `child` (see the module), fetched (`StableBytes::fetch`)
    /// and checked the first time; `None` where it is no treelet, is damaged or could not be
    /// fetched (kept as damage, see [`Bvh::damage`]: every later render fails as the one that
    /// met it, as for a damaged file, rather than some renders meeting holes unseen; the file
    /// opened again fetches anew): the walk then treats it as empty.
    #[cold]
    #[inline(never)]
    pub(crate) fn enter(&self, child: u32) -> Option<u32> {
        let t = child.checked_sub(TREELET_BASE).filter(|_| child & LEAF == 0)? as usize;
        let (lazy, treelet) = (self.lazy.as_deref()?, self.treelets.get(t)?);
        let whole = *lazy.whole[t].get_or_init(|| match self.check_treelet(treelet, lazy.depth[t]) {
            Ok(()) => true,
            Err(problem) => {
                let _ = lazy.damage.set(format!("treelet {t}: {problem}"));
                false
            }
        });
        whole.then_some(treelet.root)
    }

    /// Whether `child` names a treelet (a stored top's child).
    #[inline(always)]
    pub(crate) fn is_treelet(child: u32) -> bool {
        child & LEAF == 0 && child >= TREELET_BASE
    }

    /// The first damage a walk found in a stored tree's treelets, if any.
    pub fn damage(&self) -> Option<&str> {
        self.lazy.as_deref().and_then(Lazy::damage)
    }

    /// Every treelet checked now (for what reads all the splats); the first damage.
    pub fn check_all(&self) -> Result<(), String> {
        for t in 0..self.treelets.len() {
            self.enter(treelet_ref(t));
        }
        self.damage().map_or(Ok(()), |d| Err(d.to_string()))
    }

    /// A treelet's CRC and structure: its nodes' children lie after them within it, its leaves
    /// within its blocks, no deeper than the walks' stacks allow from `depth`, its root's.
    fn check_treelet(&self, t: &Treelet, depth: u8) -> Result<(), String> {
        self.fetch_treelet(t).map_err(|e| format!("could not be read: {e}"))?;
        if self.treelet_crc(t) != t.crc {
            return Err("damaged (CRC mismatch)".into());
        }
        let (nodes, blocks) = (t.node_range(), t.block_range());
        let leaf_within = |c: u32| {
            let b = leaf_blocks(c);
            blocks.start <= b.start && b.end <= blocks.end
        };
        if t.root & LEAF != 0 {
            return if nodes.is_empty() && leaf_within(t.root) {
                Ok(())
            } else {
                Err("a lone leaf out of place".into())
            };
        }
        if nodes.is_empty() || t.root as usize != nodes.start {
            return Err(format!("its root {} is not its first node", t.root));
        }
        let mut depths = vec![u8::MAX; nodes.len()];
        depths[0] = depth;
        for k in nodes.clone() {
            let d = depths[k - nodes.start];
            if d == u8::MAX {
                return Err(format!("node {k} has no parent before it"));
            }
            for i in used(&self.nodes[k]) {
                let c = self.nodes[k].child[i];
                if c & LEAF != 0 {
                    if !leaf_within(c) {
                        return Err(format!("node {k} child {i}: a leaf outside its blocks"));
                    }
                } else if (c as usize) <= k || c as usize >= nodes.end || usize::from(d) >= MAX_DEPTH {
                    return Err(format!("node {k} child {i}: node {c} not after it within, or too deep"));
                } else {
                    depths[c as usize - nodes.start] = d + 1;
                }
            }
        }
        Ok(())
    }

    /// Has the bytes under the tree fetch treelet `t`'s ranges, where they arrive as read
    /// (`StableBytes::fetch`): its five runs in one call.
    fn fetch_treelet(&self, t: &Treelet) -> Result<(), String> {
        let Some(bytes) = self.nodes.owner() else { return Ok(()) };
        let (nodes, blocks) = (t.node_range(), t.block_range());
        let ranges = [
            self.nodes.byte_range(nodes.clone()),
            self.lod.byte_range(nodes.clone()),
            self.representatives.byte_range(nodes.clone()),
            self.aggregates.byte_range(nodes),
            self.blocks.byte_range(blocks),
        ];
        bytes.fetch(&ranges.into_iter().flatten().collect::<Vec<_>>())
    }

    /// The CRC a scene file keeps of treelet `t`.
    pub(crate) fn treelet_crc(&self, t: &Treelet) -> u32 {
        let (nodes, blocks) = (t.node_range(), t.block_range());
        let mut crc = crc32fast::Hasher::new();
        crc.update(bytemuck::cast_slice(&self.nodes[nodes.clone()]));
        crc.update(bytemuck::cast_slice(&self.lod[nodes.clone()]));
        crc.update(bytemuck::cast_slice(&self.representatives[nodes.clone()]));
        crc.update(bytemuck::cast_slice(&self.aggregates[nodes]));
        crc.update(bytemuck::cast_slice(&self.blocks[blocks]));
        crc.finalize()
    }

    /// The lazy checks of a stored tree whose top is checked: each treelet's root depth from
    /// the top's nodes, which must name every treelet where the table says, and only top nodes
    /// after themselves.
    pub(super) fn lazy_checks(&self) -> Result<Lazy, String> {
        let top = self.top_nodes;
        let mut depth = vec![u8::MAX; top];
        let mut treelet_depth = vec![u8::MAX; self.treelets.len()];
        if let Some(root) = depth.first_mut() {
            *root = 1;
        }
        for k in 0..top {
            let d = depth[k];
            if d == u8::MAX || usize::from(d) >= MAX_DEPTH {
                return Err(format!("top node {k} has no parent before it, or lies too deep"));
            }
            for i in used(&self.nodes[k]) {
                let c = self.nodes[k].child[i];
                if Bvh::is_treelet(c) {
                    let t = (c - TREELET_BASE) as usize;
                    let named = self.treelets.get(t).is_some_and(|t| t.parent as usize == k && t.slot as usize == i);
                    if !named || treelet_depth[t] != u8::MAX {
                        return Err(format!("top node {k} child {i}: treelet {t} is not there"));
                    }
                    treelet_depth[t] = d + 1;
                } else if (c as usize) <= k || c as usize >= top {
                    return Err(format!("top node {k} child {i}: {c:#x} is no top node after it nor a treelet"));
                } else {
                    depth[c as usize] = d + 1;
                }
            }
        }
        let (n, blocks) = (self.nodes.len(), self.blocks.len());
        for (t, treelet) in self.treelets.iter().enumerate() {
            let (nodes, range) = (treelet.node_range(), treelet.block_range());
            if treelet_depth[t] == u8::MAX || nodes.start < top || nodes.start > nodes.end || nodes.end > n {
                return Err(format!("treelet {t} is unnamed or its nodes lie outside"));
            }
            if range.start > range.end || range.end > blocks {
                return Err(format!("treelet {t}'s blocks lie outside"));
            }
        }
        let whole = (0..self.treelets.len()).map(|_| OnceLock::new()).collect();
        Ok(Lazy { whole, depth: treelet_depth.into(), damage: OnceLock::new() })
    }
}

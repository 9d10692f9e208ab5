//! DBSCAN with kiddo's ImmutableKdTree: neighbourhoods listed point by point.
//!
//! The immutable tree is used on purpose: kiddo's mutable tree panics when a bucket fills with
//! equal coordinates, which LiDAR scan lines produce routinely. Exactly equal points are merged
//! first and counted with their multiplicity. Costly on dense clouds (every point lists its
//! thousands of neighbours), so it only runs where the grid cannot: one connected cloud wider
//! than the grid's cell keys (see the parent module).

use kiddo::immutable::float::kdtree::ImmutableKdTree;
use kiddo::SquaredEuclidean;

use super::clustering::{Clustering, NOISE};

/// Points per kd-tree leaf bucket (kiddo's default).
const BUCKET: usize = 32;
type Tree = ImmutableKdTree<f64, u32, 3, BUCKET>;

/// Most neighbour indices kept between the two passes (u32 each: 64 MiB). Beyond it the
/// neighbourhoods of core points are queried again while expanding, so memory stays O(N).
pub(crate) const NEIGHBOUR_BUDGET: usize = 16 << 20;

/// The kd-tree version (for a connected cloud wider than the grid's cell keys allow, and as a
/// cross-check of the grid).
pub(crate) fn dbscan_kdtree(coords: &[[f64; 3]], eps: f64, min_points: usize) -> Clustering {
    dbscan_with_budget(coords, eps, min_points, NEIGHBOUR_BUDGET)
}

/// Groups exactly equal points: returns the distinct points, their multiplicities and,
/// for each input point, the index of its distinct point. Many LiDARs report every missing
/// return as (0, 0, 0), so without this a cloud could hold one neighbourhood of N points.
fn deduplicate(coords: &[[f64; 3]]) -> (Vec<[f64; 3]>, Vec<usize>, Vec<u32>) {
    // +0.0 turns -0.0 into 0.0 so equal coordinates share a bit pattern.
    let key = |p: &[f64; 3]| [(p[0] + 0.0).to_bits(), (p[1] + 0.0).to_bits(), (p[2] + 0.0).to_bits()];
    let mut order: Vec<u32> = (0..coords.len() as u32).collect();
    order.sort_unstable_by_key(|&i| key(&coords[i as usize]));
    let mut unique: Vec<[f64; 3]> = Vec::with_capacity(coords.len());
    let mut weight: Vec<usize> = Vec::with_capacity(coords.len());
    let mut rep = vec![0u32; coords.len()];
    let mut last: Option<[u64; 3]> = None;
    for &i in &order {
        let k = key(&coords[i as usize]);
        if last != Some(k) {
            unique.push(coords[i as usize]);
            weight.push(0);
            last = Some(k);
        }
        let u = unique.len() - 1;
        weight[u] += 1;
        rep[i as usize] = u as u32;
    }
    (unique, weight, rep)
}

pub(crate) fn dbscan_with_budget(coords: &[[f64; 3]], eps: f64, min_points: usize, budget: usize) -> Clustering {
    let m = coords.len();
    if m == 0 {
        return Clustering::empty();
    }
    let (unique, weight, rep) = deduplicate(coords);
    let u_count = unique.len();
    let tree = Tree::new_from_slice(&unique);
    let eps2 = eps * eps;
    let query = |q: &[f64; 3]| tree.within_unsorted::<SquaredEuclidean>(q, eps2);

    // Pass 1: weighted neighbour count of every distinct point; the neighbourhoods of core
    // points (the only ones expanded) are kept in one flat buffer while it fits the budget.
    let mut is_core = vec![false; u_count];
    let mut starts = vec![0usize; u_count + 1];
    let mut neighbours: Vec<u32> = Vec::with_capacity(u_count * min_points.min(32));
    let mut stored = true;
    for (k, q) in unique.iter().enumerate() {
        let found = query(q);
        let count: usize = found.iter().map(|nn| weight[nn.item as usize]).sum();
        if count >= min_points {
            is_core[k] = true;
            if stored {
                if neighbours.len() + found.len() > budget {
                    stored = false;
                    neighbours = Vec::new();
                } else {
                    neighbours.extend(found.iter().map(|nn| nn.item));
                }
            }
        }
        if stored {
            starts[k + 1] = neighbours.len();
        }
    }

    // Pass 2: expand clusters from core points in input index order (sklearn's dbscan_inner).
    let mut labels = vec![NOISE; u_count];
    let mut stack: Vec<u32> = Vec::new();
    let mut next_label: i32 = 0;
    for &seed in &rep {
        if labels[seed as usize] != NOISE || !is_core[seed as usize] {
            continue;
        }
        stack.push(seed);
        while let Some(i) = stack.pop() {
            let i = i as usize;
            if labels[i] != NOISE {
                continue;
            }
            labels[i] = next_label;
            if !is_core[i] {
                continue;
            }
            if stored {
                stack.extend(neighbours[starts[i]..starts[i + 1]].iter().filter(|&&j| labels[j as usize] == NOISE));
            } else {
                stack.extend(query(&unique[i]).iter().map(|nn| nn.item).filter(|&j| labels[j as usize] == NOISE));
            }
        }
        next_label += 1;
    }
    Clustering {
        labels: rep.iter().map(|&u| labels[u as usize]).collect(),
        core: rep.iter().map(|&u| is_core[u as usize]).collect(),
    }
}

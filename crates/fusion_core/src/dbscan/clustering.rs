//! What every DBSCAN back end returns, and the merge of independent parts.

/// Label of points that belong to no cluster.
pub const NOISE: i32 = -1;

/// Labels plus core flags, both in the order of the points given.
///
/// Clusters are numbered by their first core point in that order (scikit-learn's numbering);
/// the core flags let [`merge`] renumber parts clustered separately.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Clustering {
    pub labels: Vec<i32>,
    pub core: Vec<bool>,
}

impl Clustering {
    /// No points.
    pub fn empty() -> Clustering {
        Clustering { labels: Vec::new(), core: Vec::new() }
    }
}

/// Joins clusterings of disjoint parts of one cloud that no `eps` neighbourhood crosses.
///
/// `parts[k]` holds the indices (into the whole cloud, `n` points) of part `k` and its
/// clustering. Clusters are renumbered by their first core point over the whole cloud, which is
/// scikit-learn's numbering: inside a part the relative order of clusters is unchanged, so a
/// border point's rule (the lowest-numbered cluster reaching it) still holds.
pub(crate) fn merge(n: usize, parts: &[(Vec<u32>, Clustering)]) -> Clustering {
    const UNSET: i32 = i32::MAX;
    let mut part_of = vec![(0u32, NOISE); n];
    let mut core = vec![false; n];
    let mut renumber: Vec<Vec<i32>> = Vec::with_capacity(parts.len());
    for (k, (idx, c)) in parts.iter().enumerate() {
        let clusters = c.labels.iter().copied().max().map_or(0, |m| (m + 1).max(0) as usize);
        renumber.push(vec![UNSET; clusters]);
        for ((&i, &l), &is_core) in idx.iter().zip(&c.labels).zip(&c.core) {
            part_of[i as usize] = (k as u32, l);
            core[i as usize] = is_core;
        }
    }
    let mut next = 0i32;
    for i in 0..n {
        let (k, l) = part_of[i];
        if core[i] && renumber[k as usize][l as usize] == UNSET {
            renumber[k as usize][l as usize] = next;
            next += 1;
        }
    }
    let labels = part_of.iter().map(|&(k, l)| if l == NOISE { NOISE } else { renumber[k as usize][l as usize] }).collect();
    Clustering { labels, core }
}

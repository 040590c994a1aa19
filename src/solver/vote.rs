//! A rank's vote for the next shooter, kept up to date instead of scanned:
//! the largest unshot power among its patches (the lowest patch on ties)
//! and the sum of their powers in fixed point. A shot changes the residuals
//! of the shooter and of the patches it reaches; in a big scene most shots
//! (its weak shooters' cheap transport rows) reach a few thousand of
//! hundreds of thousands of patches, and a scan of every patch a shot was
//! most of the solve (Sponza: 7.5 of 13.5 s).

/// No candidate (a leaf whose power is not positive).
const NONE: u32 = u32::MAX;

/// Per own patch its power and fixed-point share, the sum of the shares,
/// and a tournament tree whose root names the best candidate.
#[derive(Debug, Default)]
pub(super) struct Vote {
    /// What the tree was built for: (rank, ranks, patches); `None`
    /// until built, and after any change the marks do not follow.
    built: Option<(usize, usize, usize)>,
    /// Per leaf (own patch, in increasing order): its power.
    power: Vec<f64>,
    /// Per leaf: its power in fixed point.
    fixed: Vec<u64>,
    /// The sum of `fixed` (wrapping, as the scan's sum would).
    total: u64,
    /// The tree, heap-ordered (node 1 the root, leaves from `size`): each
    /// node the leaf of its subtree's best candidate, or `NONE`.
    tree: Vec<u32>,
    /// Leaves as `tree` indices start here (a power of two).
    size: usize,
    /// Leaves changed since the last refresh, and whether each is listed.
    dirty: Vec<u32>,
    listed: Vec<bool>,
}

impl Vote {
    /// Forgets the tree: the next refresh scans every patch.
    pub(super) fn invalidate(&mut self) {
        self.built = None;
    }

    /// Notes that leaf `leaf`'s residual changed.
    pub(super) fn touch(&mut self, leaf: usize) {
        if self.built.is_none() {
            return;
        }
        if let Some(l) = self.listed.get_mut(leaf) {
            if !*l {
                *l = true;
                self.dirty.push(leaf as u32);
            }
        }
    }

    /// The fixed-point sum and the best leaf (`None` when no power is
    /// positive), after bringing the tree up to date: `key` is what the
    /// solver is now (rank, ranks, patches), `leaves` the own
    /// patches' count (which the key decides), `of(leaf)` a leaf's (power,
    /// fixed-point power).
    pub(super) fn refresh(
        &mut self,
        key: (usize, usize, usize),
        leaves: usize,
        of: impl Fn(usize) -> (f64, u64),
    ) -> (u64, Option<(usize, f64)>) {
        if self.built != Some(key) {
            self.rebuild(key, leaves, &of);
        } else if !self.dirty.is_empty() {
            self.update(&of);
        }
        let best = self.tree.get(1).copied().unwrap_or(NONE);
        let best = (best != NONE).then(|| (best as usize, self.power[best as usize]));
        (self.total, best)
    }

    fn rebuild(
        &mut self,
        key: (usize, usize, usize),
        leaves: usize,
        of: &impl Fn(usize) -> (f64, u64),
    ) {
        self.power.clear();
        self.fixed.clear();
        self.total = 0;
        for k in 0..leaves {
            let (w, f) = of(k);
            self.power.push(w);
            self.fixed.push(f);
            self.total = self.total.wrapping_add(f);
        }
        self.size = leaves.next_power_of_two().max(1);
        self.tree = vec![NONE; 2 * self.size];
        for k in 0..leaves {
            self.tree[self.size + k] = self.leaf_value(k);
        }
        for node in (1..self.size).rev() {
            self.tree[node] = self.better(self.tree[2 * node], self.tree[2 * node + 1]);
        }
        self.dirty.clear();
        self.listed = vec![false; leaves];
        self.built = Some(key);
    }

    /// Recomputes the dirty leaves and their ancestors, level by level (a
    /// shot's receivers cluster in patch order, so they share most
    /// ancestors).
    fn update(&mut self, of: &impl Fn(usize) -> (f64, u64)) {
        let mut nodes = std::mem::take(&mut self.dirty);
        nodes.sort_unstable();
        for &leaf in &nodes {
            let k = leaf as usize;
            self.listed[k] = false;
            let (w, f) = of(k);
            self.total = self.total.wrapping_sub(self.fixed[k]).wrapping_add(f);
            self.power[k] = w;
            self.fixed[k] = f;
            self.tree[self.size + k] = self.leaf_value(k);
        }
        let mut level: Vec<u32> = nodes.iter().map(|&k| (self.size as u32 + k) / 2).collect();
        while level.first().is_some_and(|&n| n >= 1) {
            level.dedup();
            for &n in &level {
                let n = n as usize;
                self.tree[n] = self.better(self.tree[2 * n], self.tree[2 * n + 1]);
            }
            if level[0] == 1 {
                break;
            }
            level.iter_mut().for_each(|n| *n /= 2);
        }
        nodes.clear();
        self.dirty = nodes;
    }

    /// The `k` best leaves with their powers, best first (the tree's order:
    /// the larger power, then the lower leaf), as of the last refresh: a
    /// best-first walk down the tree, each node naming its subtree's best.
    pub(super) fn top(&self, k: usize) -> Vec<(usize, f64)> {
        #[derive(PartialEq)]
        struct Node(f64, u32, usize);
        impl Eq for Node {}
        impl PartialOrd for Node {
            fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
                Some(self.cmp(o))
            }
        }
        impl Ord for Node {
            fn cmp(&self, o: &Self) -> std::cmp::Ordering {
                self.0.total_cmp(&o.0).then(o.1.cmp(&self.1))
            }
        }
        let mut out = Vec::with_capacity(k);
        let mut heap = std::collections::BinaryHeap::new();
        let push = |heap: &mut std::collections::BinaryHeap<Node>, node: usize| {
            if let Some(&leaf) = self.tree.get(node).filter(|&&l| l != NONE) {
                heap.push(Node(self.power[leaf as usize], leaf, node));
            }
        };
        push(&mut heap, 1);
        while out.len() < k {
            let Some(Node(w, leaf, node)) = heap.pop() else {
                break;
            };
            if node >= self.size {
                out.push((leaf as usize, w));
            } else {
                push(&mut heap, 2 * node);
                push(&mut heap, 2 * node + 1);
            }
        }
        out
    }

    /// A leaf's entry: itself when its power is positive (a NaN is not).
    fn leaf_value(&self, k: usize) -> u32 {
        if self.power[k] > 0.0 {
            k as u32
        } else {
            NONE
        }
    }

    /// The better of two subtrees' bests, `a` holding the lower patches:
    /// `b` only when strictly stronger (the scan's first-of-equals rule).
    fn better(&self, a: u32, b: u32) -> u32 {
        match (a, b) {
            (_, NONE) => a,
            (NONE, _) => b,
            _ if self.power[b as usize] > self.power[a as usize] => b,
            _ => a,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The scan the tree replaces: the sum and the first strictly largest
    /// positive power.
    fn scan(power: &[f64], fixed: &[u64]) -> (u64, Option<(usize, f64)>) {
        let mut best: Option<(usize, f64)> = None;
        let mut total = 0u64;
        for (k, (&w, &f)) in power.iter().zip(fixed).enumerate() {
            total = total.wrapping_add(f);
            if w > 0.0 && best.is_none_or(|(_, b)| w > b) {
                best = Some((k, w));
            }
        }
        (total, best)
    }

    #[test]
    fn the_kept_vote_is_the_scans_after_any_changes() {
        let mut rng = crate::rng::Rng(0x5eed);
        for leaves in [0usize, 1, 2, 3, 7, 64, 1000] {
            let mut power: Vec<f64> = (0..leaves).map(|_| (rng.next_u64() % 5) as f64).collect();
            let fixed_of = |w: f64| (w * 1000.0) as u64;
            let mut vote = Vote::default();
            let key = (0, 1, leaves);
            for round in 0..50 {
                // Change a few leaves (ties, zeros, negatives and NaNs too),
                // sometimes a run of neighbours, as a shot's receivers are.
                let changes = (rng.next_u64() % 6) as usize;
                for _ in 0..changes.min(leaves) {
                    let k = (rng.next_u64() as usize) % leaves;
                    let run = 1 + (rng.next_u64() % 4) as usize;
                    let end = (k + run).min(leaves);
                    for (j, w) in power.iter_mut().enumerate().take(end).skip(k) {
                        *w = match rng.next_u64() % 7 {
                            0 => 0.0,
                            1 => -1.0,
                            2 => f64::NAN,
                            r => r as f64,
                        };
                        vote.touch(j);
                    }
                }
                let fixed: Vec<u64> = power.iter().map(|&w| fixed_of(w)).collect();
                let got = vote.refresh(key, leaves, |k| (power[k], fixed_of(power[k])));
                let want = scan(&power, &fixed);
                assert_eq!(got.0, want.0, "{leaves} leaves, round {round}: the sum");
                assert_eq!(
                    got.1.map(|(k, w)| (k, w.to_bits())),
                    want.1.map(|(k, w)| (k, w.to_bits())),
                    "{leaves} leaves, round {round}: the best"
                );
                // The top 5: a stable sort of the positive leaves by power.
                let mut sorted: Vec<(usize, f64)> = power
                    .iter()
                    .enumerate()
                    .filter(|(_, &w)| w > 0.0)
                    .map(|(k, &w)| (k, w))
                    .collect();
                sorted.sort_by(|a, b| b.1.total_cmp(&a.1));
                sorted.truncate(5);
                assert_eq!(
                    vote.top(5),
                    sorted,
                    "{leaves} leaves, round {round}: the top 5"
                );
            }
        }
    }
}

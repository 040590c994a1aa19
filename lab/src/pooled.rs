//! The renderer's pool of rows, as it dealt a batch until 2026-12-07, when
//! it was taken out (its gain, 1-3 % on two ranks, was within noise:
//! `docs/mechanisms.md`). The committed calibration runs made with it say
//! so (`settings.deal_rows: "pool"`), and the performance model replays
//! each run as it dealt.

use radiosity::parallel::assign_rows;

/// How a batch's work items were dealt by the renderer's pool of rows
/// (until 2026-12-07): some to a fixed rank, the rest to a pool that ranks
/// took from as they came free, so a rank
/// whose core runs slower this second takes fewer and none waits long for
/// the others at the batch's exchange. Only time depends on who draws what.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Deal {
    /// Per item, the rank that draws it, or `None` for the pool.
    pub fixed: Vec<Option<usize>>,
    /// The pooled items, in the order ranks take them (the costliest first,
    /// so what is left at the end is small; the later item first on ties).
    pub pool: Vec<usize>,
}

impl Deal {
    /// `costs` as for [`assign_rows`]. An item that costs some rank less
    /// (a row it has cached) is fixed, as [`assign_rows`] deals it, with
    /// the costliest `ranks` of the others, one a rank: every rank starts
    /// with work, and the pool keeps the cheaper rest. On one rank, or
    /// not `pooled`, everything is fixed as [`assign_rows`] deals it.
    pub fn new(costs: &[f64], ranks: usize, pooled: bool) -> Self {
        let ranks = ranks.max(1);
        let k = costs.len() / ranks;
        if ranks == 1 || !pooled {
            return Self {
                fixed: assign_rows(costs, ranks).into_iter().map(Some).collect(),
                pool: Vec::new(),
            };
        }
        let cost = |rank: usize, item: usize| costs[rank * k + item];
        let alike = |item: usize| (1..ranks).all(|r| cost(r, item) == cost(0, item));
        let mut pool: Vec<usize> = (0..k).filter(|&i| alike(i)).collect();
        // Among rows weighed alike the later (weaker) shooters go first:
        // the strongest, the emitters, are the likeliest to split, and a
        // split row's first round is short, which suits a pool's end.
        pool.sort_by(|&a, &b| cost(0, b).total_cmp(&cost(0, a)).then(b.cmp(&a)));
        let head: Vec<usize> = pool.drain(..ranks.min(pool.len())).collect();
        let mut fixed_items: Vec<usize> = (0..k).filter(|&i| !alike(i)).chain(head).collect();
        fixed_items.sort_unstable();
        let sub: Vec<f64> = (0..ranks)
            .flat_map(|r| fixed_items.iter().map(move |&i| cost(r, i)))
            .collect();
        let mut fixed = vec![None; k];
        for (&item, rank) in fixed_items.iter().zip(assign_rows(&sub, ranks)) {
            fixed[item] = Some(rank);
        }
        Self { fixed, pool }
    }

    /// Each rank's sum of `seconds` (per item) when the pool goes, item by
    /// item, to the rank with the least so far (the lower on ties): what
    /// ranks taking a pool's items as they come free do, at those seconds.
    pub fn loads(&self, seconds: &[f64], ranks: usize) -> Vec<f64> {
        let mut load = vec![0.0; ranks.max(1)];
        for (item, rank) in self.fixed.iter().enumerate() {
            if let Some(r) = rank {
                load[*r] += seconds[item];
            }
        }
        for &item in &self.pool {
            let least = (0..load.len())
                .min_by(|&a, &b| load[a].total_cmp(&load[b]).then(a.cmp(&b)))
                .unwrap_or(0);
            load[least] += seconds[item];
        }
        load
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_deal_fixes_cached_rows_and_one_dear_row_a_rank_and_pools_the_rest() {
        // Two ranks, six rows: row 1 cached on rank 1.
        let costs = [
            3.0, 2.0, 1.0, 5.0, 4.0, 0.5, // rank 0
            3.0, 0.02, 1.0, 5.0, 4.0, 0.5, // rank 1
        ];
        let deal = Deal::new(&costs, 2, true);
        assert_eq!(deal.fixed[1], Some(1), "the cached row on its cache's rank");
        // The two dearest alike rows (3 and 4) start the ranks, one each.
        let (a, b) = (deal.fixed[3], deal.fixed[4]);
        assert!(a.is_some() && b.is_some() && a != b, "{deal:?}");
        // The rest pooled, dearest first.
        assert_eq!(deal.pool, vec![0, 2, 5]);
        for item in 0..6 {
            assert_ne!(deal.fixed[item].is_some(), deal.pool.contains(&item));
        }
        // Taken as ranks come free: the row of 3 s goes to the rank with
        // 4 s, and so on.
        let seconds = [3.0, 0.02, 1.0, 5.0, 4.0, 0.5];
        let loads = deal.loads(&seconds, 2);
        assert!((loads.iter().sum::<f64>() - 13.52).abs() < 1e-12);
        assert!((loads[0] - loads[1]).abs() <= 1.0, "{loads:?}");
        // One rank: everything fixed there; fewer rows than ranks: no pool.
        assert_eq!(
            Deal::new(&[1.0, 2.0], 1, true).fixed,
            vec![Some(0), Some(0)]
        );
        let few = Deal::new(&[1.0, 2.0, 1.0, 2.0, 1.0, 2.0], 3, true);
        assert!(few.pool.is_empty() && few.fixed.iter().all(Option::is_some));
        // Not pooled: assign_rows's deal, every row fixed.
        let fixed = Deal::new(&costs, 2, false);
        assert!(fixed.pool.is_empty());
        let drawer: Vec<usize> = fixed.fixed.iter().map(|r| r.unwrap_or(9)).collect();
        assert_eq!(drawer, assign_rows(&costs, 2));
    }
}

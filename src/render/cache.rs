//! The form-factor row cache: rows of patches that have shot, kept for when
//! they shoot again. A row is keyed by its shooter patch, hemisphere centre
//! and resolution tier, so a hit gives exactly the values a fresh drawing
//! would. Whether a row is kept depends only on counts summed over ranks, so
//! every rank keeps or drops a row alike (and every rank hits alike).

use crate::formfactor::Row;
use std::collections::HashMap;

/// Memory the form-factor row cache may use at most, in bytes per rank
/// (summed over ranks before each decision, so every rank keeps or drops a
/// row alike); less where the rank's memory budget leaves less (see
/// [`cache_budget`]).
pub const ROW_CACHE_BYTES: u64 = 1 << 30;

/// What a rank keeps free of its memory budget beyond what it holds when
/// the cache is set up: the solver's arrays (72 bytes an element) and the
/// shots' working memory, which grows to the largest shot's rectangles
/// (Sponza: 0.45 GB in all, 0.32 GB of it for a shot of 385 000 rectangles).
pub const CACHE_HEADROOM_BYTES: u64 = 640 << 20;

/// The cache one rank may hold, bytes: what its memory budget `budget`
/// leaves once it holds `resident` bytes and keeps [`CACHE_HEADROOM_BYTES`]
/// free, at most [`ROW_CACHE_BYTES`]. The cache only saves time (a hit is
/// bit for bit a fresh row), so a small budget changes no number.
pub fn cache_budget(budget: u64, resident: u64) -> u64 {
    budget
        .saturating_sub(resident.saturating_add(CACHE_HEADROOM_BYTES))
        .min(ROW_CACHE_BYTES)
}

/// A cached row's shooter patch, hemisphere centre (f32 bits) and tier.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct RowKey {
    /// The shooter patch.
    pub patch: u32,
    /// The hemisphere's centre, as f32 bits (exact equality).
    pub centre: [u32; 3],
    /// The resolution tier (0: fine, 1: coarse).
    pub tier: u8,
}

impl RowKey {
    /// The key of a shot of `patch` at `centre` in tier `tier`.
    pub fn new(patch: u32, centre: glam::Vec3, tier: usize) -> Self {
        Self {
            patch,
            centre: centre.to_array().map(f32::to_bits),
            tier: tier as u8,
        }
    }
}

/// Rows of shooters that have shot, within a byte budget over all ranks.
#[derive(Default)]
pub struct RowCache {
    rows: HashMap<RowKey, Row>,
    /// The last row computed, until it is known whether it fits.
    pending: Option<(RowKey, Row)>,
    /// Bytes the cache holds over all ranks.
    bytes: u64,
    /// Bytes it may hold over all ranks (0: no cache).
    budget: u64,
}

impl RowCache {
    /// A cache of at most `budget` bytes over all ranks (0 keeps nothing).
    pub fn new(budget: u64) -> Self {
        Self {
            budget,
            ..Self::default()
        }
    }

    /// The cache of `ranks` ranks that may each hold `per_rank` bytes (the
    /// least any rank may: every rank must decide alike), or none.
    pub fn for_ranks(enabled: bool, per_rank: u64, ranks: usize) -> Self {
        Self::new(if enabled {
            per_rank.saturating_mul(ranks as u64)
        } else {
            0
        })
    }

    /// The budget over all ranks, bytes.
    pub fn budget(&self) -> u64 {
        self.budget
    }

    /// The row kept for `key`, if any.
    pub fn get(&self, key: &RowKey) -> Option<&Row> {
        self.rows.get(key)
    }

    /// Whether the cache keeps anything at all.
    pub fn enabled(&self) -> bool {
        self.budget > 0
    }

    /// Offers the row just computed; it is kept or dropped at the next
    /// [`RowCache::settle`], once every rank's share of its size is known.
    pub fn offer(&mut self, key: RowKey, mut row: Row) {
        if self.enabled() {
            // A row grows by pushes: kept, it holds only what it uses.
            row.shrink_to_fit();
            self.pending = Some((key, row));
        }
    }

    /// Bytes of the offered row not yet decided on (this rank's share).
    pub fn pending_bytes(&self) -> u64 {
        self.pending.as_ref().map_or(0, |(_, r)| r.bytes() as u64)
    }

    /// Keeps the offered row if the cache has room for `all_ranks_bytes`
    /// (its bytes summed over ranks: the same number on every rank).
    pub fn settle(&mut self, all_ranks_bytes: u64) {
        if let Some((key, row)) = self.pending.take() {
            if self.bytes + all_ranks_bytes <= self.budget {
                self.bytes += all_ranks_bytes;
                self.rows.insert(key, row);
            }
        }
    }

    /// Rows kept.
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    /// Whether no row is kept.
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(n: usize) -> Row {
        Row {
            columns: 1,
            ids: (0..n as u32).collect(),
            values: vec![0.5; n],
            ..Row::default()
        }
    }

    fn key(patch: u32) -> RowKey {
        RowKey::new(patch, glam::Vec3::new(1.0, 2.0, 3.0), 0)
    }

    #[test]
    fn a_row_is_kept_only_once_settled_and_within_the_budget() {
        let one = row(10).bytes() as u64;
        let mut c = RowCache::new(2 * one);
        c.offer(key(0), row(10));
        assert!(c.get(&key(0)).is_none(), "not before it is settled");
        assert_eq!(c.pending_bytes(), one);
        c.settle(one);
        assert_eq!(c.get(&key(0)), Some(&row(10)));
        assert_eq!(c.pending_bytes(), 0);
        // Another rank's share makes the next row too big for what is left.
        c.offer(key(1), row(10));
        c.settle(one + 1);
        assert!(c.get(&key(1)).is_none());
        c.offer(key(2), row(10));
        c.settle(one);
        assert!(c.get(&key(2)).is_some());
        assert_eq!(c.len(), 2);
    }

    #[test]
    fn keys_tell_centres_and_tiers_apart() {
        let mut c = RowCache::new(u64::MAX);
        c.offer(key(3), row(2));
        c.settle(1);
        let moved = RowKey::new(3, glam::Vec3::new(1.0, 2.0, 3.0000002), 0);
        let coarse = RowKey::new(3, glam::Vec3::new(1.0, 2.0, 3.0), 1);
        assert!(c.get(&moved).is_none() && c.get(&coarse).is_none());
        assert!(c.get(&key(3)).is_some());
    }

    #[test]
    fn a_disabled_cache_keeps_nothing() {
        let mut c = RowCache::for_ranks(false, ROW_CACHE_BYTES, 4);
        c.offer(key(0), row(3));
        assert_eq!(c.pending_bytes(), 0);
        c.settle(0);
        assert!(c.is_empty());
        assert_eq!(
            RowCache::for_ranks(true, ROW_CACHE_BYTES, 4).budget(),
            4 * ROW_CACHE_BYTES
        );
    }

    #[test]
    fn the_cache_takes_what_the_memory_budget_leaves_at_most_its_cap() {
        let gb = 1_000_000_000;
        // Sponza after its set-up: 1.14 GB held of 2 GB.
        let b = cache_budget(2 * gb, 1_142_000_000);
        assert_eq!(b, 2 * gb - 1_142_000_000 - CACHE_HEADROOM_BYTES);
        assert_eq!(cache_budget(64 * gb, gb), ROW_CACHE_BYTES);
        assert_eq!(cache_budget(2 * gb, 3 * gb), 0, "over budget: no cache");
        assert_eq!(cache_budget(0, 0), 0);
    }
}

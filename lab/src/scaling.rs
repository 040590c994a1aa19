//! The performance model of `docs/scaling.md`: what a shot costs on N
//! ranks, fitted to measured runs and extrapolated to the paper's 64
//! processors and beyond.
//!
//! Per shot, on N ranks,
//!
//! ```text
//! T(N) = R + (D / N) (1 + u(N)) + calls L(N) alpha + bytes(N) / beta
//! ```
//!
//! - `R`, the replicated seconds, and `D`, the divided ones, per phase:
//!   from the 1-rank time T1 = R + D and the 2-rank mean over ranks
//!   M2 = R + D / 2, both one core per rank;
//! - `u(N)`, the imbalance: the slowest rank's divided work over the mean
//!   less one, from the measured load balance epsilon = T_min / T_max of
//!   each shot's busy CPU seconds at 2-16 ranks (more ranks than cores
//!   inflate wall times, not CPU seconds), fitted as u0 N^gamma;
//! - the exchange: `calls` collectives a shot (measured), each a tree of
//!   L(N) = ceil(log2 N) stages of latency `alpha`, plus the bytes a rank
//!   receives over bandwidth `beta`. Bytes by the exchange's law:
//!   partial hemispheres B (N - 1) / N of the hemisphere's B bytes;
//!   partial form factors one dense array per stage over ceil(log2 N) + 1
//!   stages; sparse pairs to their owners, a rank's distinct receivers
//!   V (1 - exp(-cells / (N V))) of V visible ones. With the paper's own
//!   schedule (its AP1000+), a partial-hemisphere exchange takes N stages.
//!   Beside the exchange, the occlusion cull's all-gather of the polygons
//!   each rank saw (bytes fitted as a power of N) and, where the ranks deal
//!   the bounds, the all-to-all of rectangles to their tiles' owners (a
//!   rank's share falling as a fitted power of N, N - 1 messages a call).
//!   Batched shots exchange their rows in one all-to-all a step (a batch,
//!   and a round for its split shots' groups), and rows pooled as ranks
//!   come free cost a ticket each, a round trip to rank 0 (see
//!   [`Model::stages`]).
//!
//! The module reads reports as JSON and knows nothing of GPUs or MPI.

use serde_json::Value;
use std::path::{Path, PathBuf};

/// Why runs could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ScalingError {
    /// A report could not be read.
    #[error("cannot read {path}: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// A report lacks a figure the model needs.
    #[error("{path}: {what}")]
    Report {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
}

/// The phases of a shot the report times per rank, in report order.
pub const PHASES: [&str; 6] = [
    "select_shooter",
    "bounds",
    "rasterise",
    "read_back",
    "sum_form_factors",
    "update",
];

/// One measured run, per shot.
#[derive(Clone, Debug, Default)]
pub struct Run {
    /// File it came from.
    pub path: PathBuf,
    /// Scene name.
    pub scene: String,
    /// Hemisphere resolution, rows x columns.
    pub resolution: [u32; 2],
    /// Ranks.
    pub ranks: usize,
    /// The exchange (`hemispheres`, `form-factors` or `sparse`).
    pub exchange: String,
    /// Shots of the final solve.
    pub shots: f64,
    /// Seconds of the final solve (the refinement passes left out).
    pub solve: f64,
    /// Per rank, per phase ([`PHASES`]), seconds per shot.
    pub phases: Vec<[f64; 6]>,
    /// Per rank, bytes received per shot (the exchange's).
    pub bytes: Vec<f64>,
    /// Per rank, bytes of the occlusion cull's agreement received per shot.
    pub occlusion_bytes: Vec<f64>,
    /// Per rank, bytes of dealt rectangles received per shot (0 where the
    /// ranks did not deal the bounds).
    pub rect_bytes: Vec<f64>,
    /// Per rank, collective calls per shot.
    pub calls: Vec<f64>,
    /// Per rank, process CPU seconds per shot outside collective calls.
    pub cpu_own: Vec<f64>,
    /// Per rank, hemisphere cells drawn per shot.
    pub cells: Vec<f64>,
    /// Cells of one whole hemisphere.
    pub hemisphere_cells: f64,
    /// Mean load balance of the shots' busy CPU seconds.
    pub epsilon_cpu: f64,
    /// Batched runs: per rank, CPU seconds a shot drawing rows (the
    /// divided work; empty in reports without it).
    pub rows_cpu: Vec<f64>,
    /// Batched runs: every row in shot order as (its step: twice the shot
    /// its batch began at, plus its round (1: a split shot's groups, dealt
    /// after the rows), its weight in the assignment, its CPU seconds, the
    /// rank that drew it).
    pub rows: Vec<(u64, f64, f64, usize)>,
    /// Batched runs: whether the rows were pooled (`crate::pooled`; the
    /// renderer dealt them so from 2026-12-04 to 2026-12-07, by default).
    pub pooled: bool,
}

impl Run {
    /// Reads a `radiosity render` report.
    pub fn read(path: &Path) -> Result<Self, ScalingError> {
        let text = std::fs::read_to_string(path).map_err(|source| ScalingError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let bad = |what: String| ScalingError::Report {
            path: path.to_path_buf(),
            what,
        };
        let v: Value = serde_json::from_str(&text).map_err(|e| bad(format!("not JSON: {e}")))?;
        let num = |x: &Value, name: &str| {
            x.as_f64()
                .ok_or_else(|| bad(format!("no number `{name}` (a report of this version?)")))
        };
        let shots = num(&v["shots"], "shots")?;
        if shots < 1.0 {
            return Err(bad("no shots".into()));
        }
        let p = &v["parallel"];
        let per_rank = p["per_rank"]
            .as_array()
            .filter(|a| !a.is_empty())
            .ok_or_else(|| bad("no `parallel.per_rank`".into()))?;
        let mut run = Run {
            path: path.to_path_buf(),
            scene: v["scene"].as_str().unwrap_or("?").to_string(),
            resolution: [
                num(&v["settings"]["resolution"]["rows"], "rows")? as u32,
                num(&v["settings"]["resolution"]["cols"], "cols")? as u32,
            ],
            ranks: per_rank.len(),
            // Batched shots (`--batch`) are their own decomposition, fitted
            // against 1-rank runs of the same batch.
            exchange: match p["batch"].as_u64() {
                Some(b) if b > 1 => format!("batches-{b}"),
                _ => p["exchange"].as_str().unwrap_or("?").to_string(),
            },
            shots,
            solve: num(&v["timings"]["solve"], "solve")?
                - num(&v["refinement"]["seconds"], "refinement.seconds")?,
            hemisphere_cells: num(&v["counts"]["cells"], "cells")?,
            epsilon_cpu: num(&p["load_balance_cpu"]["mean"], "load_balance_cpu")?,
            rows: p["rows"]
                .as_array()
                .map(|rows| {
                    rows.iter()
                        .filter_map(|r| {
                            // A round of a batch is a step of its own:
                            // every rank waits for the round's slowest.
                            let round = r["round"].as_u64().unwrap_or(0);
                            Some((
                                2 * r["batch_start"].as_u64()? + round.min(1),
                                r["cost"].as_f64()?,
                                r["cpu_seconds"].as_f64()?,
                                r["rank"].as_u64()? as usize,
                            ))
                        })
                        .collect()
                })
                .unwrap_or_default(),
            pooled: v["settings"]["deal_rows"].as_str() == Some("pool"),
            // Per rank, filled below.
            ..Run::default()
        };
        for r in per_rank {
            let mut ph = [0.0; 6];
            for (k, name) in PHASES.iter().enumerate() {
                ph[k] = num(&r[*name], name)? / shots;
            }
            run.phases.push(ph);
            run.bytes
                .push(num(&r["bytes_received"], "bytes_received")? / shots);
            run.occlusion_bytes
                .push(num(&r["occlusion_bytes_received"], "occlusion_bytes_received")? / shots);
            run.rect_bytes
                .push(num(&r["rect_bytes_received"], "rect_bytes_received")? / shots);
            run.calls.push(num(&r["mpi_calls"], "mpi_calls")? / shots);
            run.cpu_own.push(
                (num(&r["cpu_seconds"], "cpu_seconds")?
                    - num(&r["mpi_cpu_seconds"], "mpi_cpu_seconds")?)
                    / shots,
            );
            run.cells.push(num(&r["cells"], "cells")? / shots);
            if let Some(x) = r["rows_cpu_seconds"].as_f64() {
                run.rows_cpu.push(x / shots);
            }
        }
        if run.rows_cpu.len() != run.ranks {
            run.rows_cpu.clear();
        }
        Ok(run)
    }

    /// The mean over ranks of each phase, seconds per shot.
    pub fn mean_phases(&self) -> [f64; 6] {
        let mut m = [0.0; 6];
        for ph in &self.phases {
            for k in 0..6 {
                m[k] += ph[k] / self.ranks as f64;
            }
        }
        m
    }

    /// Mean over ranks of a per-rank figure.
    pub fn mean(v: &[f64]) -> f64 {
        v.iter().sum::<f64>() / v.len().max(1) as f64
    }

    /// Batched runs: the slowest rank's row CPU seconds, batch by batch
    /// (each batch waits for its slowest rank), a shot.
    pub fn slowest_rows(&self) -> f64 {
        let mut total = 0.0;
        for batch in self.rows.chunk_by(|a, b| a.0 == b.0) {
            let mut load = vec![0.0; self.ranks];
            for &(_, _, cpu, rank) in batch {
                if let Some(l) = load.get_mut(rank) {
                    *l += cpu;
                }
            }
            total += load.iter().copied().fold(0.0, f64::max);
        }
        total / self.shots
    }

    /// Batched runs: the steps their recorded rows were drawn in (a batch,
    /// and a second round where it split shots), each ended by one
    /// all-to-all of the rows.
    pub fn steps(&self) -> f64 {
        let mut steps: Vec<u64> = self.rows.iter().map(|r| r.0).collect();
        steps.sort_unstable();
        steps.dedup();
        steps.len() as f64
    }

    /// Hemispheres drawn per shot (split shots draw several, coarse ones
    /// fewer cells).
    pub fn hemispheres(&self) -> f64 {
        self.cells.iter().sum::<f64>() / self.hemisphere_cells
    }

    /// Seconds per shot of the final solve.
    pub fn seconds_per_shot(&self) -> f64 {
        self.solve / self.shots
    }
}

/// A network: latency per stage and bandwidth per link.
#[derive(Clone, Copy, Debug)]
pub struct Network {
    /// Name for tables and charts.
    pub name: &'static str,
    /// Seconds per message stage.
    pub latency: f64,
    /// Bytes per second a rank receives.
    pub bandwidth: f64,
    /// Whether partial hemispheres go in the paper's N broadcast stages
    /// (else a recursive-doubling all-gather's ceil(log2 N)).
    pub paper_schedule: bool,
}

/// The AP1000+ of the paper: its T-net links are of the 25 MB/s class
/// (the issue's figure); 20 us a message stage is our assumption for its
/// put/get latency, which the paper does not give.
pub const AP1000: Network = Network {
    name: "AP1000+ (25 MB/s, 20 us)",
    latency: 20e-6,
    bandwidth: 25e6,
    paper_schedule: true,
};

/// A current cluster interconnect (InfiniBand EDR class: 100 Gb/s, about
/// 12 GB/s delivered, 2 us a stage through MPI).
pub const CLUSTER: Network = Network {
    name: "cluster (12 GB/s, 2 us)",
    latency: 2e-6,
    bandwidth: 12e9,
    paper_schedule: false,
};

/// `at2 (n / 2)^power`: the model's laws of what grows or falls with the
/// rank count from its value on 2 ranks.
fn from_two(at2: f64, power: f64, n: f64) -> f64 {
    at2 * (n / 2.0).powf(power)
}

/// ceil(log2 n), 0 for one rank.
fn log2_stages(n: f64) -> f64 {
    if n <= 1.0 {
        0.0
    } else {
        n.log2().ceil()
    }
}

/// One phase's fit: seconds per shot every rank repeats, and seconds per
/// shot divided among the ranks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhaseFit {
    /// Replicated seconds per shot.
    pub replicated: f64,
    /// Divided seconds per shot (on one rank).
    pub divided: f64,
}

impl PhaseFit {
    /// From the 1-rank time and the 2-rank mean over ranks: T1 = R + D,
    /// M2 = R + D / 2, each clamped to [0, T1] (noise can put M2 above T1
    /// or under T1 / 2).
    pub fn from_times(t1: f64, m2: f64) -> Self {
        let divided = (2.0 * (t1 - m2)).clamp(0.0, t1.max(0.0));
        Self {
            replicated: t1.max(0.0) - divided,
            divided,
        }
    }
}

/// How the exchange's bytes grow with the rank count: what a rank receives
/// a shot is `items (N - 1) / N` (partial hemispheres: every other rank's
/// cells), plus `dense` (partial form factors: one array per stage, over
/// ceil(log2 N) + 1 stages), plus sparse pairs sent to their owners (the
/// sparse exchange's sums, or the hybrid method's covered-cell counts).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Bytes {
    /// Bytes of every rank's cells of a shot's hemispheres.
    pub items: f64,
    /// Bytes of one dense array a shot.
    pub dense: f64,
    /// Sparse pairs, if any.
    pub pairs: Option<Pairs>,
    /// The bounds' deal: rectangles sent to their tiles' owners, if the
    /// ranks deal.
    pub rects: Option<Pairs>,
    /// The occlusion cull's all-gather of the polygons each rank saw.
    pub occlusion: Growth,
}

/// Bytes that grow (or fall) as a power of the rank count:
/// `at2 (N / 2)^power` a rank receives a shot.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Growth {
    /// Bytes a rank receives a shot on 2 ranks.
    pub at2: f64,
    /// The power of N / 2.
    pub power: f64,
}

impl Growth {
    /// Bytes a rank receives a shot on `n` ranks.
    pub fn received(&self, n: f64) -> f64 {
        if n <= 1.0 {
            0.0
        } else {
            from_two(self.at2, self.power, n)
        }
    }
}

/// Items sent to the ranks that own them ((element, value) pairs to the
/// elements' owners, rectangles to their tiles'): a rank sends
/// `at2 (N / 2)^-delta` items a shot, (N - 1) / N of them to others, of
/// `size` bytes each, and a 4-byte count to every rank per call.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pairs {
    /// Pairs a rank sends a shot on 2 ranks.
    pub at2: f64,
    /// How fast they fall with the rank count (1: as the cells).
    pub delta: f64,
    /// All-to-all calls a shot.
    pub calls: f64,
    /// Bytes an item takes.
    pub size: f64,
}

/// Bytes a pair takes (u32 element, u64 fixed-point value).
pub const PAIR_BYTES: f64 = 12.0;
/// Bytes a dealt rectangle takes (its proxy and its cell rectangle: the
/// receiver rebuilds the rest).
pub const RECT_BYTES: f64 = 20.0;
/// Bytes of the count an all-to-all sends each rank.
pub const COUNT_BYTES: f64 = 4.0;

impl Pairs {
    /// Pairs a rank sends a shot on `n` ranks.
    pub fn sent(&self, n: f64) -> f64 {
        from_two(self.at2, -self.delta, n)
    }

    /// Bytes a rank receives a shot on `n` ranks.
    pub fn received(&self, n: f64) -> f64 {
        self.size * self.sent(n) * (n - 1.0) / n + COUNT_BYTES * n * self.calls
    }

    /// Items a rank sent a shot, from the bytes it received on `n` ranks
    /// in `calls` all-to-alls of items of `size` bytes.
    fn from_received(bytes: f64, n: f64, calls: f64, size: f64) -> f64 {
        ((bytes - COUNT_BYTES * n * calls) * n / ((n - 1.0) * size)).max(0.0)
    }
}

impl Bytes {
    /// Bytes a rank receives a shot on `n` ranks.
    pub fn received(&self, n: f64) -> f64 {
        if n <= 1.0 {
            return 0.0;
        }
        self.exchanged(n) + self.beside(n)
    }

    /// Of those, the exchange's bytes.
    pub fn exchanged(&self, n: f64) -> f64 {
        if n <= 1.0 {
            return 0.0;
        }
        self.items * (n - 1.0) / n + self.dense + self.pairs.map_or(0.0, |p| p.received(n))
    }

    /// Of those, the occlusion cull's and the bounds' deal's.
    pub fn beside(&self, n: f64) -> f64 {
        if n <= 1.0 {
            return 0.0;
        }
        self.occlusion.received(n) + self.rects.map_or(0.0, |p| p.received(n))
    }

    /// Bytes that cross a rank's links a shot: the dense array once per stage.
    pub fn on_the_wire(&self, n: f64) -> f64 {
        if n <= 1.0 {
            return 0.0;
        }
        self.received(n) + self.dense * log2_stages(n)
    }
}

/// The fitted model of one scene, resolution and exchange.
#[derive(Clone, Debug)]
pub struct Model {
    /// Scene.
    pub scene: String,
    /// Resolution, rows x columns.
    pub resolution: [u32; 2],
    /// Exchange.
    pub exchange: String,
    /// Per phase ([`PHASES`]), from the 1- and 2-rank wall times: where the
    /// time goes (descriptive; the law below is what predicts).
    pub phases: [PhaseFit; 6],
    /// One rank's compute seconds a shot (CPU, outside collectives).
    pub serial: f64,
    /// On two or more ranks, a rank's compute seconds a shot are
    /// `replicated + divided / N`: what every rank repeats, the decomposition's
    /// own work (ownership culls, the gathered hemisphere's scan) included.
    pub replicated: f64,
    /// ... and what the ranks share.
    pub divided: f64,
    /// Collective calls a shot (a pooled batch's tickets apart: see
    /// [`Replay::tickets`]).
    pub calls: f64,
    /// Hemispheres drawn a shot.
    pub hemispheres: f64,
    /// The bytes' law.
    pub bytes: Bytes,
    /// The imbalance u(N) = imbalance2 (N / 2)^gamma.
    pub imbalance2: f64,
    /// Growth of the imbalance with the rank count.
    pub gamma: f64,
    /// The most ranks the divided work splits over: a batch's shots
    /// (`batches-K`: K rows a step; more ranks wait), else unbounded.
    pub split_limit: f64,
    /// Batched shots with their rows recorded: the rows replayed on N
    /// ranks, which takes the place of `divided` and `u(N)` (see [`Replay`]).
    pub replay: Option<Replay>,
}

/// A batched run's rows replayed on any number of ranks: every batch's
/// rows with the weights the render dealt them by and the CPU seconds they
/// took on one rank, dealt again as the render deals them
/// ([`radiosity::parallel::Deal`]: one of the dearest rows a rank, the rest
/// taken by whichever rank comes free first). The slowest rank's rows set a
/// batch's time, so the imbalance is the rows' own, not a fitted law. A
/// rank's CPU seconds outside its rows follow `rest_a + s rest_b / N`,
/// where s is the rows' contention on N ranks (1 on one rank): the divided
/// rest (the display transport's rays, the landing) is memory-bound work
/// like the rows, and costs two busy cores more as they do; on this
/// machine beyond its 2 cores, times the rows' growth there.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Replay {
    /// Per batch, each row's (weight, CPU seconds).
    pub batches: Vec<Vec<(f64, f64)>>,
    /// Shots of the run.
    pub shots: f64,
    /// CPU seconds a shot every rank spends outside its rows (the vote, the
    /// choice, the rows' exchange, the landing's bookkeeping)...
    pub rest_a: f64,
    /// ... and what of it the ranks divide (the landing on a rank's own
    /// elements, the display transport's rays).
    pub rest_b: f64,
    /// The rows' CPU seconds on 2 ranks, one core each, over one rank's:
    /// what two busy cores sharing caches and memory cost each other.
    pub contention2: f64,
    /// With more ranks than this machine's 2 cores the rows' CPU seconds
    /// grow further, as `contention2 (N / 2)^contention_power` (time
    /// slicing); one core a rank stays at `contention2`.
    pub contention_power: f64,
}

impl Replay {
    /// From a run's rows (batch start, weight, CPU seconds, rank).
    pub fn from_rows(rows: &[(u64, f64, f64, usize)], shots: f64) -> Self {
        Self {
            batches: rows
                .chunk_by(|a, b| a.0 == b.0)
                .map(|batch| batch.iter().map(|&(_, w, cpu, _)| (w, cpu)).collect())
                .collect(),
            shots,
            contention2: 1.0,
            ..Self::default()
        }
    }

    /// All-to-alls a shot: one a step (a batch's rows; its split shots'
    /// groups, a second round), on any rank count.
    pub fn all_to_alls(&self) -> f64 {
        self.batches.len() as f64 / self.shots
    }

    /// Tickets a rank takes a shot on `n` ranks, the rows `pooled` (each a
    /// round trip to the pool's counter on rank 0) or dealt before any is
    /// drawn (none): of each step's pool (the rows the deal does not fix,
    /// one of the dearest a rank), 1 / n of them, and one each rank takes
    /// past its end.
    pub fn tickets(&self, n: f64, pooled: bool) -> f64 {
        if !pooled || n <= 1.0 {
            return 0.0;
        }
        let ranks = n as usize;
        let mut tickets = 0.0;
        for batch in &self.batches {
            let weights: Vec<f64> = (0..ranks).flat_map(|_| batch.iter().map(|r| r.0)).collect();
            let pool = crate::pooled::Deal::new(&weights, ranks, true).pool.len();
            if pool > 0 {
                tickets += pool as f64 / n + 1.0;
            }
        }
        tickets / self.shots
    }

    /// Row CPU seconds a shot on one rank.
    pub fn rows(&self) -> f64 {
        self.batches.iter().flatten().map(|r| r.1).sum::<f64>() / self.shots
    }

    /// The most and the least row CPU seconds a shot a rank draws on `n`
    /// ranks, batch by batch, at one rank's speed, the rows `pooled` as the
    /// render pools them by default or all dealt before any is drawn.
    pub fn loads(&self, n: usize, pooled: bool) -> (f64, f64) {
        let n = n.max(1);
        let (mut most, mut least) = (0.0, 0.0);
        for batch in &self.batches {
            // Every rank weighs a row alike here (no row caches).
            let weights: Vec<f64> = (0..n).flat_map(|_| batch.iter().map(|r| r.0)).collect();
            let seconds: Vec<f64> = batch.iter().map(|r| r.1).collect();
            let load = crate::pooled::Deal::new(&weights, n, pooled).loads(&seconds, n);
            most += load.iter().copied().fold(0.0, f64::max);
            least += load.iter().copied().fold(f64::INFINITY, f64::min);
        }
        (most / self.shots, least / self.shots)
    }

    /// The rows' contention on `n` ranks: on this machine (`here`, its 2
    /// cores time-sliced beyond 2 ranks), or one core a rank.
    pub fn contention(&self, n: f64, here: bool) -> f64 {
        if n <= 1.0 {
            1.0
        } else if here && n > 2.0 {
            from_two(self.contention2, self.contention_power, n)
        } else {
            self.contention2
        }
    }

    /// A rank's CPU seconds a shot outside its rows on `n` ranks, one
    /// core a rank: its divided part slowed by the cores' contention as
    /// the rows are.
    pub fn rest(&self, n: f64) -> f64 {
        let n = n.max(1.0);
        self.rest_a + self.contention(n, false) * self.rest_b / n
    }

    /// The same on `n` ranks of this machine (`here`), where beyond its 2
    /// cores time slicing slows it as it slows the rows.
    pub fn rest_on(&self, n: f64, here: bool) -> f64 {
        let slicing = if self.contention2 > 0.0 {
            self.contention(n, here) / self.contention2
        } else {
            1.0
        };
        self.rest(n) * if here && n > 2.0 { slicing } else { 1.0 }
    }
}

impl Model {
    /// The ranks the divided work is split over on `n` ranks.
    fn busy(&self, n: f64) -> f64 {
        n.min(self.split_limit)
    }

    /// The imbalance u(N): the slowest rank's divided work over the mean,
    /// less one (0 on one rank; at most 1, when one rank has twice its share).
    pub fn imbalance(&self, n: f64) -> f64 {
        if n <= 1.0 {
            0.0
        } else {
            from_two(self.imbalance2, self.gamma, n).min(1.0)
        }
    }

    /// A rank's mean compute seconds a shot on `n` ranks, one core each.
    pub fn compute_mean(&self, n: f64) -> f64 {
        self.compute_mean_on(n, false)
    }

    /// ... on `n` ranks of this machine (`here`: beyond its 2 cores they
    /// share them), or one core each.
    pub fn compute_mean_on(&self, n: f64, here: bool) -> f64 {
        if n <= 1.0 {
            self.serial
        } else if let Some(r) = &self.replay {
            r.rest_on(n, here) + r.contention(n, here) * r.rows() / n
        } else {
            self.replicated + self.divided / self.busy(n)
        }
    }

    /// The slowest rank's compute seconds a shot.
    pub fn compute_max(&self, n: f64) -> f64 {
        if n <= 1.0 {
            self.serial
        } else if let Some(r) = &self.replay {
            r.rest(n) + r.contention(n, false) * r.loads(n as usize, false).0
        } else {
            let m = self.busy(n);
            self.replicated + self.divided / m * (1.0 + self.imbalance(m))
        }
    }

    /// The load balance epsilon = T_min / T_max the model expects.
    pub fn epsilon(&self, n: f64) -> f64 {
        if n <= 1.0 {
            return 1.0;
        }
        if let Some(r) = &self.replay {
            let (most, least) = r.loads(n as usize, false);
            let c = r.contention(n, false);
            return (r.rest(n) + c * least) / (r.rest(n) + c * most);
        }
        let q = self.divided / self.busy(n);
        let u = self.imbalance(self.busy(n));
        (self.replicated + q * (1.0 - u)) / (self.replicated + q * (1.0 + u))
    }

    /// Latencies a shot on `n` ranks: `calls` collectives of ceil(log2 N)
    /// stages each, with the paper's own schedule (`paper_schedule`) N
    /// broadcasts a hemisphere instead of a tree, N - 1 messages an
    /// all-to-all of pairs or dealt rectangles (the renderer deals a batch's
    /// rows before drawing them, so no pooled row's ticket).
    pub fn stages(&self, n: f64, paper_schedule: bool) -> f64 {
        if n <= 1.0 {
            return 0.0;
        }
        let mut stages = self.calls * log2_stages(n);
        if paper_schedule && self.bytes.items > 0.0 {
            stages += self.hemispheres * (n - log2_stages(n));
        }
        for p in self.bytes.pairs.iter().chain(&self.bytes.rects) {
            stages += p.calls * (n - 1.0 - log2_stages(n));
        }
        stages
    }

    /// Exchange seconds a shot on `n` ranks over `net`.
    pub fn exchange(&self, n: f64, net: &Network) -> f64 {
        if n <= 1.0 {
            return 0.0;
        }
        self.stages(n, net.paper_schedule) * net.latency + self.bytes.on_the_wire(n) / net.bandwidth
    }

    /// Seconds a shot on `n` ranks over `net`.
    pub fn seconds_per_shot(&self, n: f64, net: &Network) -> f64 {
        self.compute_max(n) + self.exchange(n, net)
    }

    /// Speedup on `n` ranks over `net` against one rank.
    pub fn speedup(&self, n: f64, net: &Network) -> f64 {
        self.seconds_per_shot(1.0, net) / self.seconds_per_shot(n, net)
    }

    /// The speedup no rank count passes: one rank's seconds over the
    /// replicated ones.
    pub fn amdahl_limit(&self) -> f64 {
        self.serial / self.replicated
    }
}

/// Solves epsilon = (R + q (1 - u)) / (R + q (1 + u)) for u.
pub fn imbalance_from_epsilon(epsilon: f64, replicated: f64, divided_share: f64) -> f64 {
    if divided_share <= 0.0 {
        return 0.0;
    }
    ((replicated + divided_share) * (1.0 - epsilon) / (divided_share * (1.0 + epsilon)))
        .clamp(0.0, 1.0)
}

/// The power p of `at2 (N / 2)^p` through `(ranks, value)` points beyond 2
/// ranks, by least squares in logs (NaN with none to fit, or nothing at 2).
fn power_through(at2: f64, points: impl Iterator<Item = (usize, f64)>) -> f64 {
    let (num, den) =
        points
            .filter(|&(_, y)| y > 0.0 && at2 > 0.0)
            .fold((0.0, 0.0), |(a, b), (n, y)| {
                let x = (n as f64 / 2.0).ln();
                (a + x * (y / at2).ln(), b + x * x)
            });
    if den > 0.0 {
        num / den
    } else {
        f64::NAN
    }
}

/// Least squares of y = a x0 + b x1 with a, b >= 0.
fn least_squares_2(rows: &[(f64, f64, f64)]) -> (f64, f64) {
    let (mut s00, mut s01, mut s11, mut t0, mut t1) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for &(x0, x1, y) in rows {
        s00 += x0 * x0;
        s01 += x0 * x1;
        s11 += x1 * x1;
        t0 += x0 * y;
        t1 += x1 * y;
    }
    let det = s00 * s11 - s01 * s01;
    let one = |s: f64, t: f64| if s > 0.0 { (t / s).max(0.0) } else { 0.0 };
    if det.abs() > 1e-12 * s00 * s11 && det != 0.0 {
        let a = (t0 * s11 - t1 * s01) / det;
        let b = (s00 * t1 - s01 * t0) / det;
        if a >= 0.0 && b >= 0.0 {
            return (a, b);
        }
    }
    // One of them at zero: the better of the two one-parameter fits.
    let (a, b) = (one(s00, t0), one(s11, t1));
    let err = |a: f64, b: f64| {
        rows.iter()
            .map(|&(x0, x1, y)| (y - a * x0 - b * x1).powi(2))
            .sum::<f64>()
    };
    if err(a, 0.0) <= err(0.0, b) {
        (a, 0.0)
    } else {
        (0.0, b)
    }
}

/// The whole calibration: the runs, this machine's network, and a model
/// per scene, resolution and exchange.
#[derive(Clone, Debug)]
pub struct Calibration {
    /// Every run read.
    pub runs: Vec<Run>,
    /// The most ranks a run the fit used may have (the others are only
    /// checked against).
    pub fitted_up_to: usize,
    /// This machine's shared-memory "network", fitted to what the 2-rank
    /// wall times leave over the slowest rank's compute.
    pub local: Network,
    /// The models.
    pub models: Vec<Model>,
}

impl Calibration {
    /// Fits the models to every run.
    pub fn fit(runs: Vec<Run>) -> Result<Self, ScalingError> {
        Self::fit_up_to(runs, usize::MAX)
    }

    /// Fits the models to the runs of at most `max_ranks` ranks: every scene
    /// and resolution needs a 1-rank run and a 2-rank run per exchange;
    /// hemisphere runs on more ranks (CPU seconds) pin the compute law.
    pub fn fit_up_to(runs: Vec<Run>, max_ranks: usize) -> Result<Self, ScalingError> {
        // Every repeat, for each batched row's least CPU seconds.
        let all = runs.clone();
        let runs = fastest_of_repeats(runs);
        let used = |r: &&Run| r.ranks <= max_ranks;
        // A batched run's 1-rank run is of the same batch; the exchanges'
        // is any other (one rank exchanges nothing).
        let one = |scene: &str, res: [u32; 2], exchange: &str| {
            let batched = |ex: &str| ex.starts_with("batches");
            runs.iter().find(|r| {
                r.ranks == 1
                    && r.scene == scene
                    && r.resolution == res
                    && if batched(exchange) {
                        r.exchange == exchange
                    } else {
                        !batched(&r.exchange)
                    }
            })
        };
        // replicated + divided / N through the mean CPU seconds of an
        // exchange's runs on 2 or more ranks, when there are 2 rank counts.
        let law = |scene: &str, res: [u32; 2], exchange: &str| {
            let rows: Vec<(f64, f64, f64)> = runs
                .iter()
                .filter(used)
                .filter(|r| {
                    r.ranks >= 2
                        && r.scene == scene
                        && r.resolution == res
                        && r.exchange == exchange
                })
                .map(|r| (1.0, 1.0 / r.ranks as f64, Run::mean(&r.cpu_own)))
                .collect();
            (rows.len() > 1).then(|| least_squares_2(&rows))
        };
        let mut models = Vec::new();
        let mut net_rows = Vec::new();
        for two in runs.iter().filter(|r| r.ranks == 2) {
            let Some(single) = one(&two.scene, two.resolution, &two.exchange) else {
                return Err(ScalingError::Report {
                    path: two.path.clone(),
                    what: format!(
                        "no 1-rank run of {} at {}x{} to fit it against",
                        two.scene, two.resolution[0], two.resolution[1]
                    ),
                });
            };
            let t1 = single.mean_phases();
            let m2 = two.mean_phases();
            let mut phases = [PhaseFit::from_times(0.0, 0.0); 6];
            for k in 0..6 {
                phases[k] = PhaseFit::from_times(t1[k], m2[k]);
            }
            // The compute law: an exchange's own runs on 2 and more ranks
            // when there are two rank counts; else the hemisphere runs' divided
            // part (the drawing and the sums a rank does are the same whatever
            // the exchange) and the exchange's own 2-rank CPU seconds for the
            // replicated part (its bookkeeping differs).
            let y2 = Run::mean(&two.cpu_own);
            let own = law(&two.scene, two.resolution, &two.exchange);
            let (replicated, divided) = match own.or(law(&two.scene, two.resolution, "hemispheres"))
            {
                Some((a, d)) if own.is_some() => (a, d),
                Some((_, d)) => (y2 - d / 2.0, d),
                None => {
                    // Only 2 ranks: the phases' split.
                    let d: f64 = phases.iter().map(|p| p.divided).sum();
                    (y2 - d / 2.0, d)
                }
            };
            let calls = Run::mean(&two.calls);
            let hemispheres = single.hemispheres();
            let b2 = Run::mean(&two.bytes);
            // Every rank's cells of a shot's hemispheres, 4 bytes each.
            let items = 4.0 * single.cells.iter().sum::<f64>();
            // Pairs go in one all-to-all a hemisphere; a batched run's rows
            // in one a step (a batch, and a second round for its split shots'
            // groups), counted from its rows where it recorded them.
            let pair_calls = match two.exchange.strip_prefix("batches-") {
                Some(_) if !two.rows.is_empty() => two.steps() / two.shots,
                Some(k) => 1.0 / k.parse::<f64>().unwrap_or(1.0).max(1.0),
                None => hemispheres,
            };
            // This exchange's runs beyond 2 ranks, which give the bytes' fall.
            let more = || {
                runs.iter()
                    .filter(used)
                    .filter(|r| r.ranks > 2 && key(r) == key(two))
            };
            let mut bytes = match two.exchange.as_str() {
                "hemispheres" => Bytes {
                    items,
                    ..Bytes::default()
                },
                "form-factors" => Bytes {
                    dense: b2,
                    ..Bytes::default()
                },
                _ => Bytes::default(),
            };
            if two.exchange != "form-factors" {
                // What the items leave of the 2-rank bytes is pairs; runs on
                // more ranks of this exchange give their fall.
                let pairs_at = |r: &Run| {
                    let n = r.ranks as f64;
                    let rest = Run::mean(&r.bytes) - bytes.items * (n - 1.0) / n;
                    Pairs::from_received(rest, n, pair_calls, PAIR_BYTES)
                };
                let at2 = pairs_at(two);
                bytes.pairs = Some(Pairs {
                    at2,
                    delta: -power_through(at2, more().map(|r| (r.ranks, pairs_at(r)))),
                    calls: pair_calls,
                    size: PAIR_BYTES,
                });
            }
            // Beside the exchange: the cull's lists, and the dealt rectangles
            // (one all-to-all a hemisphere) where the 2-rank run dealt.
            let occlusion_at2 = Run::mean(&two.occlusion_bytes);
            bytes.occlusion = Growth {
                at2: occlusion_at2,
                power: power_through(
                    occlusion_at2,
                    more().map(|r| (r.ranks, Run::mean(&r.occlusion_bytes))),
                ),
            };
            let rects_at = |r: &Run| {
                let rest = Run::mean(&r.rect_bytes);
                Pairs::from_received(rest, r.ranks as f64, hemispheres, RECT_BYTES)
            };
            if Run::mean(&two.rect_bytes) > 0.0 {
                let at2 = rects_at(two);
                bytes.rects = Some(Pairs {
                    at2,
                    delta: -power_through(at2, more().map(|r| (r.ranks, rects_at(r)))),
                    calls: hemispheres,
                    size: RECT_BYTES,
                });
            }
            let mut model = Model {
                scene: two.scene.clone(),
                resolution: two.resolution,
                exchange: two.exchange.clone(),
                phases,
                serial: Run::mean(&single.cpu_own),
                replicated: replicated.max(0.0),
                divided,
                calls,
                hemispheres,
                bytes,
                imbalance2: 0.0,
                gamma: 0.0,
                split_limit: two
                    .exchange
                    .strip_prefix("batches-")
                    .and_then(|k| k.parse::<f64>().ok())
                    .unwrap_or(f64::INFINITY),
                replay: None,
            };
            // Imbalance: u(N) = u2 (N / 2)^gamma, least squares in logs
            // through every run of this scene's hemispheres beyond 2 ranks.
            let u = |r: &Run| {
                let n = r.ranks as f64;
                (
                    n,
                    imbalance_from_epsilon(r.epsilon_cpu, model.replicated, model.divided / n),
                )
            };
            model.imbalance2 = u(two).1;
            // Batched shots' imbalance is their own; the exchanges share the
            // hemispheres' (the drawing is the same).
            let grows_as = if two.exchange.starts_with("batches") {
                two.exchange.as_str()
            } else {
                "hemispheres"
            };
            let more: Vec<(f64, f64)> = runs
                .iter()
                .filter(used)
                .filter(|r| {
                    r.ranks > 2
                        && r.scene == two.scene
                        && r.resolution == two.resolution
                        && r.exchange == grows_as
                })
                .map(u)
                .filter(|&(_, u)| u > 0.0)
                .collect();
            if !more.is_empty() && model.imbalance2 > 0.0 {
                let (num, den) = more.iter().fold((0.0, 0.0), |(a, b), &(n, u)| {
                    let x = (n / 2.0).ln();
                    (a + x * (u / model.imbalance2).ln(), b + x * x)
                });
                model.gamma = (num / den).max(0.0);
            } else {
                model.gamma = f64::NAN;
            }
            // Batched shots whose rows were recorded: replayed (the rows'
            // own imbalance), with the rest of a rank's CPU seconds fitted
            // as a + s b / N through every rank count, and the rows' CPU
            // seconds on N ranks over one rank's as the contention s (the
            // rest's divided work, the transport's rays and the landing,
            // is of the rows' kind and slows as they do on busy cores;
            // fitted as a + b / N, that excess counted as work every rank
            // repeats at any N).
            let own_runs: Vec<&Run> = runs
                .iter()
                .filter(used)
                .filter(|r| key(r) == key(two) && !r.rows_cpu.is_empty())
                .collect();
            if two.exchange.starts_with("batches") && !single.rows.is_empty() && own_runs.len() > 1
            {
                let rows = least_rows(&all, single, max_ranks);
                let mut replay = Replay::from_rows(&rows, single.shots);
                let rows1 = replay.rows();
                let contention = |r: &Run| r.rows_cpu.iter().sum::<f64>() / rows1;
                let contention2 = contention(two);
                // Oversubscribed ranks slow their other work as they slow
                // their rows (time slicing: each rank's caches refilled
                // after the others'), so a run beyond 2 ranks gives its
                // rest at one core a rank divided by its rows' own growth.
                let rest: Vec<(f64, f64, f64)> = own_runs
                    .iter()
                    .map(|r| {
                        let rest: Vec<f64> = r
                            .cpu_own
                            .iter()
                            .zip(&r.rows_cpu)
                            .map(|(c, w)| c - w)
                            .collect();
                        let slicing = if r.ranks > 2 && contention2 > 0.0 {
                            (contention(r) / contention2).max(1.0)
                        } else {
                            1.0
                        };
                        let shared = if r.ranks > 1 { contention2 } else { 1.0 };
                        (1.0, shared / r.ranks as f64, Run::mean(&rest) / slicing)
                    })
                    .collect();
                let (a, b) = least_squares_2(&rest);
                replay.rest_a = a.max(0.0);
                replay.rest_b = b.max(0.0);
                replay.contention2 = contention2;
                replay.contention_power = power_through(
                    replay.contention2,
                    own_runs
                        .iter()
                        .filter(|r| r.ranks > 2)
                        .map(|r| (r.ranks, contention(r))),
                );
                if replay.contention_power.is_nan() {
                    replay.contention_power = 0.0;
                }
                // The 2-rank run's calls count the tickets it took (none if it
                // dealt its rows); the model adds them again for each rank count.
                model.calls = (calls - replay.tickets(2.0, two.pooled)).max(0.0);
                model.replicated = replay.rest_a;
                model.divided = replay.rest_b + rows1;
                model.imbalance2 = f64::NAN;
                model.gamma = f64::NAN;
                model.replay = Some(replay);
            }
            // The exchange is what the 2-rank wall time leaves over the
            // slowest rank's compute (waits in collectives are the
            // imbalance, already counted there).
            net_rows.push((
                model.stages(2.0, false),
                model.bytes.on_the_wire(2.0),
                two.seconds_per_shot() - model.compute_max(2.0),
            ));
            models.push(model);
        }
        // Pairs without runs beyond 2 ranks fall as the mean of those with,
        // per exchange; so do the cull's lists and the dealt rectangles.
        for ex in ["hemispheres", "sparse"] {
            let known: Vec<f64> = models
                .iter()
                .filter(|m| m.exchange == ex)
                .filter_map(|m| m.bytes.pairs.map(|p| p.delta))
                .filter(|d| !d.is_nan())
                .collect();
            let mean = mean_or(&known, 1.0);
            for m in models.iter_mut().filter(|m| m.exchange == ex) {
                if let Some(p) = m.bytes.pairs.as_mut() {
                    if p.delta.is_nan() {
                        p.delta = mean;
                    }
                }
            }
        }
        let known: Vec<f64> = models
            .iter()
            .filter_map(|m| m.bytes.rects.map(|p| p.delta))
            .filter(|d| !d.is_nan())
            .collect();
        let mean = mean_or(&known, 1.0);
        for m in &mut models {
            if let Some(p) = m.bytes.rects.as_mut() {
                if p.delta.is_nan() {
                    p.delta = mean;
                }
            }
        }
        let known: Vec<f64> = models
            .iter()
            .map(|m| m.bytes.occlusion.power)
            .filter(|d| !d.is_nan())
            .collect();
        let mean = mean_or(&known, 0.0);
        for m in models
            .iter_mut()
            .filter(|m| m.bytes.occlusion.power.is_nan())
        {
            m.bytes.occlusion.power = mean;
        }
        // Scenes without runs beyond 2 ranks take the mean growth of those
        // with, batched shots apart.
        for batched in [false, true] {
            let kind =
                |m: &Model| m.exchange.starts_with("batches") == batched && m.replay.is_none();
            let known: Vec<f64> = models
                .iter()
                .filter(|m| kind(m))
                .map(|m| m.gamma)
                .filter(|g| !g.is_nan())
                .collect();
            let pooled = mean_or(&known, 0.5);
            for m in models.iter_mut().filter(|m| kind(m) && m.gamma.is_nan()) {
                m.gamma = pooled;
            }
        }
        let (latency, inv_bw) = least_squares_2(&net_rows);
        let local = Network {
            name: "this machine (shared memory)",
            latency,
            bandwidth: if inv_bw > 0.0 {
                1.0 / inv_bw
            } else {
                f64::INFINITY
            },
            paper_schedule: false,
        };
        Ok(Self {
            runs,
            fitted_up_to: max_ranks,
            local,
            models,
        })
    }

    /// The model of a scene, resolution and exchange.
    pub fn model(&self, scene: &str, res: [u32; 2], exchange: &str) -> Option<&Model> {
        self.models
            .iter()
            .find(|m| m.scene == scene && m.resolution == res && m.exchange == exchange)
    }

    /// Every prediction that can be set against a measurement.
    pub fn validation(&self) -> Vec<Check> {
        let mut out = Vec::new();
        for r in &self.runs {
            let exchange = if r.ranks == 1 && !r.exchange.starts_with("batches") {
                "hemispheres"
            } else {
                r.exchange.as_str()
            };
            let Some(m) = self.model(&r.scene, r.resolution, exchange) else {
                continue;
            };
            let n = r.ranks as f64;
            let what = |quantity: &'static str, measured: f64, predicted: f64| Check {
                scene: r.scene.clone(),
                resolution: r.resolution,
                exchange: r.exchange.clone(),
                ranks: r.ranks,
                quantity,
                measured,
                predicted,
            };
            out.push(what(
                "mean CPU seconds a shot",
                Run::mean(&r.cpu_own),
                m.compute_mean_on(n, true),
            ));
            if r.ranks <= 2 {
                // One core per rank: wall times.
                out.push(what(
                    "seconds a shot",
                    r.seconds_per_shot(),
                    m.seconds_per_shot(n, &self.local),
                ));
            } else if m.replay.is_none() {
                // Oversubscribed: the balance of the CPU seconds.
                out.push(what(LOAD_BALANCE, r.epsilon_cpu, m.epsilon(n)));
            }
            if let (Some(replay), false) = (&m.replay, r.rows_cpu.is_empty()) {
                if r.ranks > 1 {
                    // The replay's deal against the run's own: the slowest
                    // rank's rows (the run dealt by its own row caches), as
                    // the run dealt them (oversubscribed runs fix every row:
                    // who comes free first there is the scheduler's choice).
                    out.push(what(
                        SLOWEST_ROWS,
                        r.slowest_rows(),
                        replay.contention(n, true) * replay.loads(r.ranks, r.pooled).0,
                    ));
                    // The calls: the collectives, and the tickets of rows
                    // taken from a pool (the oversubscribed runs deal theirs).
                    let taken = replay.tickets(n, r.pooled);
                    out.push(what(CALLS, Run::mean(&r.calls), m.calls + taken));
                }
            }
            if r.ranks > 1 {
                out.push(what(
                    "bytes a shot",
                    Run::mean(&r.bytes),
                    m.bytes.exchanged(n),
                ));
                let beside = Run::mean(&r.occlusion_bytes) + Run::mean(&r.rect_bytes);
                if beside > 0.0 {
                    out.push(what(BESIDE, beside, m.bytes.beside(n)));
                }
            }
        }
        out
    }
}

/// `of`'s batched rows, each at its least CPU seconds over every run of
/// one core a rank (at most `max_ranks`) of the same scene, resolution and
/// batch: every run draws the same rows (the same bits), and a row only
/// ever gets dearer from its neighbours on the machine.
fn least_rows(all: &[Run], of: &Run, max_ranks: usize) -> Vec<(u64, f64, f64, usize)> {
    let mut rows = of.rows.clone();
    let count = rows.len();
    for r in all
        .iter()
        .filter(|r| r.ranks <= 2.min(max_ranks) && key(r) == key(of) && r.rows.len() == count)
    {
        for (mine, theirs) in rows.iter_mut().zip(&r.rows) {
            if mine.0 == theirs.0 {
                mine.2 = mine.2.min(theirs.2);
            }
        }
    }
    rows
}

/// The mean of `values`, or `default` when there are none.
fn mean_or(values: &[f64], default: f64) -> f64 {
    if values.is_empty() {
        default
    } else {
        Run::mean(values)
    }
}

/// Of runs repeated (same scene, resolution, exchange and ranks), the one
/// with the fewest seconds a shot: these machines are shared, and a run
/// only ever gets slower from its neighbours.
pub fn fastest_of_repeats(runs: Vec<Run>) -> Vec<Run> {
    let mut kept: Vec<Run> = Vec::new();
    for r in runs {
        match kept
            .iter_mut()
            .find(|k| key(k) == key(&r) && k.ranks == r.ranks)
        {
            // Oversubscribed, the wall time holds the waits for a core:
            // the least CPU is the run the neighbours slowed least.
            Some(k) if r.ranks > 2 && Run::mean(&r.cpu_own) < Run::mean(&k.cpu_own) => *k = r,
            Some(k) if r.ranks <= 2 && r.seconds_per_shot() < k.seconds_per_shot() => *k = r,
            Some(_) => {}
            None => kept.push(r),
        }
    }
    kept
}

/// Keys runs by scene, resolution and exchange.
fn key(r: &Run) -> (&str, [u32; 2], &str) {
    (&r.scene, r.resolution, &r.exchange)
}

/// A prediction set against a measurement.
#[derive(Clone, Debug)]
pub struct Check {
    /// Scene.
    pub scene: String,
    /// Resolution.
    pub resolution: [u32; 2],
    /// Exchange.
    pub exchange: String,
    /// Ranks.
    pub ranks: usize,
    /// What is compared.
    pub quantity: &'static str,
    /// Measured.
    pub measured: f64,
    /// Predicted.
    pub predicted: f64,
}

impl Check {
    /// (predicted - measured) / measured.
    pub fn relative_error(&self) -> f64 {
        (self.predicted - self.measured) / self.measured
    }

    /// Whether it checks seconds or bytes (not a load balance, which the
    /// model only describes).
    pub fn is_cost(&self) -> bool {
        self.quantity != LOAD_BALANCE
    }

    /// A Markdown table row: scene, resolution, exchange, ranks, quantity,
    /// measured, predicted, error.
    pub fn row(&self) -> String {
        format!(
            "| {} | {}x{} | {} | {} | {} | {:.4e} | {:.4e} | {:+.1} % |",
            self.scene,
            self.resolution[0],
            self.resolution[1],
            self.exchange,
            self.ranks,
            self.quantity,
            self.measured,
            self.predicted,
            self.relative_error() * 100.0
        )
    }
}

/// The quantity of a load-balance check.
pub const LOAD_BALANCE: &str = "load balance (CPU)";
/// The quantity of a check of the bytes beside the exchange (the occlusion
/// cull's lists and the dealt rectangles).
pub const BESIDE: &str = "cull and deal bytes a shot";
/// A batched run's slowest rank's row CPU seconds a shot, against the
/// replay's deal of the same rows.
pub const SLOWEST_ROWS: &str = "slowest rank's rows CPU seconds a shot";

/// A batched run's MPI calls a rank makes a shot (collectives and pool
/// tickets), against the model's count.
pub const CALLS: &str = "calls a shot";

/// Reads every `*.json` report in `dir`, sorted by name.
pub fn read_runs(dir: &Path) -> Result<Vec<Run>, ScalingError> {
    let entries = std::fs::read_dir(dir).map_err(|source| ScalingError::Read {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut paths: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    paths.sort();
    paths.iter().map(|p| Run::read(p)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_phase_splits_into_replicated_and_divided() {
        let f = PhaseFit::from_times(10.0, 6.0);
        assert!((f.replicated - 2.0).abs() < 1e-12 && (f.divided - 8.0).abs() < 1e-12);
        // Noise above T1 is all replicated; below T1 / 2 all divided.
        assert_eq!(PhaseFit::from_times(1.0, 1.1).divided, 0.0);
        assert_eq!(PhaseFit::from_times(1.0, 0.4).replicated, 0.0);
    }

    /// A partial-hemisphere model of 128 x 512 cells: one rank 0.1 s a shot,
    /// 0.01 s of it replicated, four calls a shot.
    fn model(divided: f64, imbalance2: f64, gamma: f64) -> Model {
        let zero = PhaseFit {
            replicated: 0.0,
            divided: 0.0,
        };
        Model {
            scene: "s".into(),
            resolution: [128, 512],
            exchange: "hemispheres".into(),
            phases: [zero; 6],
            serial: 0.1,
            replicated: 0.01,
            divided,
            calls: 4.0,
            hemispheres: 1.0,
            bytes: Bytes {
                items: 262144.0,
                ..Bytes::default()
            },
            imbalance2,
            gamma,
            split_limit: f64::INFINITY,
            replay: None,
        }
    }

    #[test]
    fn a_replay_deals_rows_by_their_weights_and_times_them_by_their_cpu() {
        // One batch of four rows alike in weight, the first four times dearer.
        let rows = [
            (0, 1.0, 4.0, 0),
            (0, 1.0, 1.0, 0),
            (0, 1.0, 1.0, 0),
            (0, 1.0, 1.0, 0),
        ];
        let r = Replay::from_rows(&rows, 4.0);
        assert_eq!(r.batches.len(), 1);
        assert!((r.rows() - 7.0 / 4.0).abs() < 1e-12);
        assert_eq!(r.loads(1, true), (7.0 / 4.0, 7.0 / 4.0));
        // Two ranks, fixed: rows 0 and 2 to rank 0 (ties to the lower rank).
        assert_eq!(r.loads(2, false), (5.0 / 4.0, 2.0 / 4.0));
        // Pooled: rows 3 and 2 start the ranks, then row 1 goes to rank 0
        // and the dear row 0 to rank 1, whichever is free first.
        assert_eq!(r.loads(2, true), (5.0 / 4.0, 2.0 / 4.0));
        // More ranks than rows: the dearest row alone sets the time.
        assert_eq!(r.loads(8, true), (4.0 / 4.0, 0.0));
        // A second batch starts at another shot.
        let two = Replay::from_rows(&[(0, 1.0, 1.0, 0), (5, 0.5, 2.0, 0)], 2.0);
        assert_eq!(two.batches.len(), 2);
        assert_eq!(two.loads(2, true).0, 3.0 / 2.0);
    }

    #[test]
    fn a_batched_run_exchanges_once_a_step_and_takes_a_ticket_a_pooled_row() {
        // Two steps of 100 shots: a batch of 10 rows, then a second round of
        // 3 groups of its split shots.
        let mut rows: Vec<(u64, f64, f64, usize)> = (0..10).map(|_| (0, 1.0, 1.0, 0)).collect();
        rows.extend((0..3).map(|_| (1, 1.0, 1.0, 0)));
        let run = Run {
            exchange: "batches-10".into(),
            shots: 100.0,
            rows: rows.clone(),
            pooled: true,
            ..Run::default()
        };
        assert_eq!(run.steps(), 2.0);
        let r = Replay::from_rows(&rows, 100.0);
        assert!((r.all_to_alls() - 0.02).abs() < 1e-12);
        // 2 ranks: each fixes one row a step; the pools of 8 and 1 give a
        // rank half of them and one ticket past each pool's end.
        assert!((r.tickets(2.0, true) - (9.0 / 2.0 + 2.0) / 100.0).abs() < 1e-12);
        // 16 ranks: every row fixed, no pool, no ticket; dealt, none either.
        assert_eq!(r.tickets(16.0, true), 0.0);
        assert_eq!(r.tickets(2.0, false), 0.0);
        // The latencies: the collectives' trees, N - 1 messages for each
        // step's all-to-all (one of the collectives), 2 a ticket.
        let mut m = model(0.1, 0.0, 0.0);
        m.bytes = Bytes {
            pairs: Some(Pairs {
                at2: 100.0,
                delta: 1.0,
                calls: r.all_to_alls(),
                size: PAIR_BYTES,
            }),
            ..Bytes::default()
        };
        m.replay = Some(r.clone());
        for n in [2.0, 8.0, 64.0] {
            let want = 4.0 * log2_stages(n) + 0.02 * (n - 1.0 - log2_stages(n));
            assert!((m.stages(n, false) - want).abs() < 1e-12, "{n}");
        }
    }

    #[test]
    fn time_slicing_slows_a_ranks_rest_as_it_slows_its_rows() {
        let r = Replay {
            rest_a: 1.0,
            rest_b: 4.0,
            contention2: 1.1,
            contention_power: 0.5,
            ..Replay::default()
        };
        // One core a rank: the rest as fitted, wherever; its divided part
        // shares the cores' contention with the rows (1.1 on any ranks).
        assert_eq!(r.rest(1.0), 5.0);
        assert_eq!(r.rest_on(8.0, false), r.rest(8.0));
        assert!((r.rest_on(2.0, true) - (1.0 + 1.1 * 2.0)).abs() < 1e-12);
        assert!((r.rest(64.0) - (1.0 + 1.1 * 4.0 / 64.0)).abs() < 1e-12);
        // 8 ranks on this machine's 2 cores: (8 / 2)^0.5 = 2 times.
        assert!((r.rest_on(8.0, true) - 2.0 * (1.0 + 1.1 * 0.5)).abs() < 1e-12);
    }

    #[test]
    fn a_batch_splits_over_at_most_its_shots() {
        let mut m = model(0.095, 0.05, 0.5);
        m.exchange = "batches-16".into();
        m.split_limit = 16.0;
        assert_eq!(m.compute_max(64.0), m.compute_max(16.0));
        assert!(m.compute_max(16.0) < m.compute_max(8.0));
        let free = model(0.095, 0.05, 0.5);
        assert!(free.compute_max(64.0) < free.compute_max(16.0));
    }

    #[test]
    fn imbalance_inverts_epsilon() {
        let m = model(0.095, 0.05, 0.5);
        for n in [2.0, 8.0, 64.0] {
            let u = imbalance_from_epsilon(m.epsilon(n), m.replicated, m.divided / n);
            assert!((u - m.imbalance(n)).abs() < 1e-9, "{n}: {u}");
        }
        // Amdahl's limit: one rank's seconds over the replicated ones.
        assert!(m.speedup(1e9, &CLUSTER) < m.amdahl_limit() + 1e-6);
        // T(2) = R + D / 2 (1 + u2) + calls alpha + items / 2 / beta.
        let t2 = 0.01 + 0.095 / 2.0 * 1.05 + 4.0 * 2e-6 + 131072.0 / 12e9;
        assert!((m.speedup(2.0, &CLUSTER) - 0.1 / t2).abs() < 1e-9);
    }

    #[test]
    fn the_deal_and_the_cull_cost_their_bytes_and_messages() {
        let plain = model(0.09, 0.0, 0.0);
        let rects = Pairs {
            at2: 1000.0,
            delta: 1.0,
            calls: 1.0,
            size: RECT_BYTES,
        };
        let occlusion = Growth {
            at2: 2000.0,
            power: 0.5,
        };
        let mut dealt = plain.clone();
        dealt.bytes.rects = Some(rects);
        dealt.bytes.occlusion = occlusion;
        for n in [2.0, 64.0, 1024.0] {
            // The exchange's bytes are untouched; the deal's and the cull's
            // come beside them.
            assert_eq!(dealt.bytes.exchanged(n), plain.bytes.exchanged(n));
            let beside = rects.received(n) + occlusion.received(n);
            assert!((dealt.bytes.beside(n) - beside).abs() < 1e-9);
            // A rank sends 1000 (2 / N) rectangles, (N - 1) / N to others.
            let sent = 1000.0 * 2.0 / n;
            let expect = RECT_BYTES * sent * (n - 1.0) / n + COUNT_BYTES * n;
            assert!((rects.received(n) - expect).abs() < 1e-6, "{n}");
            // The all-to-all takes N - 1 messages where the other calls
            // take a tree's ceil(log2 N) stages.
            let extra = dealt.exchange(n, &CLUSTER) - plain.exchange(n, &CLUSTER);
            let stages = n - 1.0 - log2_stages(n);
            let want = stages * CLUSTER.latency + beside / CLUSTER.bandwidth;
            assert!((extra - want).abs() < 1e-12, "{n}: {extra} {want}");
        }
        assert_eq!(dealt.bytes.beside(1.0), 0.0);
    }

    #[test]
    fn a_power_is_fitted_through_the_points_in_logs() {
        let p = power_through(100.0, [(4, 200.0), (8, 400.0), (16, 800.0)].into_iter());
        assert!((p - 1.0).abs() < 1e-12);
        assert!(power_through(100.0, std::iter::empty()).is_nan());
        assert!(power_through(0.0, [(4, 1.0)].into_iter()).is_nan());
    }

    #[test]
    fn pairs_round_trip_through_their_bytes() {
        let p = Pairs {
            at2: 5000.0,
            delta: 0.8,
            calls: 1.2,
            size: RECT_BYTES,
        };
        for n in [2.0, 8.0] {
            let back = Pairs::from_received(p.received(n), n, p.calls, p.size);
            assert!((back - p.sent(n)).abs() < 1e-6, "{n}");
        }
    }

    #[test]
    fn least_squares_recovers_latency_and_bandwidth() {
        let rows: Vec<(f64, f64, f64)> = [(3.0, 1e5), (5.0, 2e6), (4.0, 5e5)]
            .iter()
            .map(|&(c, b)| (c, b, c * 3e-6 + b / 2e9))
            .collect();
        let (a, inv) = least_squares_2(&rows);
        assert!((a - 3e-6).abs() < 1e-12 && (1.0 / inv - 2e9).abs() < 1e3);
    }
}

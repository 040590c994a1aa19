//! Frame-time statistics: what the side panel shows and what
//! `--frame-stats` writes for the benchmarks.

/// Frame times over the last few hundred frames.
#[derive(Default)]
pub struct FrameTimes {
    /// Milliseconds spent in `ui` per frame.
    ui: std::collections::VecDeque<f64>,
    /// Milliseconds from one frame's start to the next's.
    interval: std::collections::VecDeque<f64>,
    /// eframe's CPU time per frame (UI, tessellation, painting), ms.
    cpu: std::collections::VecDeque<f64>,
    last: Option<std::time::Instant>,
    count: u64,
}

/// What `--frame-stats` writes: the frame times, and how far the solve got
/// in how much solve time (pauses left out).
#[derive(serde::Serialize)]
pub struct BenchStats {
    /// The frame times.
    #[serde(flatten)]
    pub frames: FrameSummary,
    /// Shots so far.
    pub shots: u64,
    /// Solve seconds so far (pauses left out).
    pub solve_seconds: f64,
    /// Whether the stop rule was met.
    pub converged: bool,
}

/// The frame times `--frame-stats` writes (and the side panel shows).
#[derive(serde::Serialize)]
pub struct FrameSummary {
    /// Frames painted.
    pub frames: u64,
    /// Median milliseconds in the UI code.
    pub ui_ms_median: f64,
    /// Most milliseconds in the UI code.
    pub ui_ms_max: f64,
    /// Median eframe CPU milliseconds per frame.
    pub cpu_ms_median: f64,
    /// 95th percentile of eframe CPU milliseconds per frame.
    pub cpu_ms_p95: f64,
    /// Median milliseconds from one frame's start to the next's.
    pub interval_ms_median: f64,
    /// 95th percentile of that.
    pub interval_ms_p95: f64,
    /// The last view image's drawing time on the view thread, ms.
    pub view_ms: f64,
}

impl FrameTimes {
    const KEEP: usize = 600;

    /// Records eframe's CPU time for the last frame.
    pub fn record_cpu(&mut self, ms: f64) {
        self.cpu.push_back(ms);
        while self.cpu.len() > Self::KEEP {
            self.cpu.pop_front();
        }
    }

    /// Records a frame that started at `start` and ends now.
    pub fn record(&mut self, start: std::time::Instant) {
        let now = std::time::Instant::now();
        self.ui.push_back((now - start).as_secs_f64() * 1e3);
        if let Some(last) = self.last {
            self.interval.push_back((start - last).as_secs_f64() * 1e3);
        }
        self.last = Some(start);
        self.count += 1;
        for q in [&mut self.ui, &mut self.interval] {
            while q.len() > Self::KEEP {
                q.pop_front();
            }
        }
    }

    /// Medians and percentiles over the frames kept.
    pub fn summary(&self, view_ms: f64) -> FrameSummary {
        let quantile = |q: &std::collections::VecDeque<f64>, f: f64| {
            let mut v: Vec<f64> = q.iter().copied().collect();
            v.sort_by(f64::total_cmp);
            v.get(((v.len() as f64 - 1.0) * f).round().max(0.0) as usize)
                .copied()
                .unwrap_or(0.0)
        };
        FrameSummary {
            frames: self.count,
            ui_ms_median: quantile(&self.ui, 0.5),
            ui_ms_max: quantile(&self.ui, 1.0),
            cpu_ms_median: quantile(&self.cpu, 0.5),
            cpu_ms_p95: quantile(&self.cpu, 0.95),
            interval_ms_median: quantile(&self.interval, 0.5),
            interval_ms_p95: quantile(&self.interval, 0.95),
            view_ms,
        }
    }
}

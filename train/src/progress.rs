//! Training progress for people: an indicatif bar on a terminal, plain log lines otherwise.

use std::io::IsTerminal;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};
use jsae_learner::UpdateMetrics;

/// Reports progress of a run.
#[derive(Debug)]
pub struct Progress {
    bar: Option<ProgressBar>,
    total: u64,
    last_logged: u64,
    phases: PhaseReporter,
}

/// Reports what a run does before its first update (random play, pre-training with the time
/// left) where the step count says little: the bar's message on a terminal, else a log line
/// for each new phase and at most every 2 s within one. Cloned into the embedder trainer's pre-training observer.
#[derive(Debug, Clone)]
pub struct PhaseReporter {
    bar: Option<ProgressBar>,
    shown: bool,
    last_logged: Arc<Mutex<Option<(Instant, String)>>>,
}

impl PhaseReporter {
    /// Shows `message` (and `env_steps` on the bar where given).
    pub fn report(&self, env_steps: Option<u64>, message: &str) {
        if let Some(bar) = &self.bar {
            if let Some(steps) = env_steps {
                bar.set_position(steps.min(bar.length().unwrap_or(steps)));
            }
            bar.set_message(message.to_string());
            return;
        }
        if !self.shown {
            return;
        }
        // a new phase (the words before the colon) is logged at once, the same one again
        // after 2 s
        let kind = message.split(':').next().unwrap_or(message).to_string();
        let mut last = self.last_logged.lock().unwrap_or_else(|e| e.into_inner());
        let due = match &*last {
            Some((t, k)) => *k != kind || t.elapsed() >= Duration::from_secs(2),
            None => true,
        };
        if due {
            *last = Some((Instant::now(), kind));
            tracing::info!("{message}");
        }
    }
}

impl Progress {
    /// A bar on a terminal (stderr), log lines otherwise; `quiet` shows nothing.
    pub fn new(total_env_steps: u64, quiet: bool) -> Self {
        let bar = (!quiet && std::io::stderr().is_terminal()).then(|| {
            let bar = ProgressBar::new(total_env_steps);
            let style = ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} steps ({per_sec}) {msg}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar());
            bar.set_style(style);
            bar
        });
        let phases = PhaseReporter {
            bar: bar.clone(),
            shown: !quiet,
            last_logged: Arc::new(Mutex::new(None)),
        };
        Self {
            bar,
            total: if quiet { 0 } else { total_env_steps },
            last_logged: 0,
            phases,
        }
    }

    /// What the run does before its first update ([`PhaseReporter`]).
    pub fn phase(&self, env_steps: Option<u64>, message: &str) {
        self.phases.report(env_steps, message);
    }

    /// A reporter of phases for another owner (the embedder trainer's observer).
    pub fn phases(&self) -> PhaseReporter {
        self.phases.clone()
    }

    /// A learner update finished.
    pub fn update(&mut self, m: &UpdateMetrics) {
        let ret = m.return_mean.map_or("-".into(), |r| format!("{r:.3}"));
        let success = m
            .success_rate
            .map_or(String::new(), |s| format!(" success {s:.2}"));
        if let Some(bar) = &self.bar {
            bar.set_position(m.env_steps.min(self.total));
            bar.set_message(format!("return {ret}{success}"));
        } else if self.total > 0
            && (m.env_steps - self.last_logged >= self.total / 20 || m.update == 1)
        {
            self.last_logged = m.env_steps;
            tracing::info!(
                "update {} env_steps {}/{} return {ret}{success} kl {:.4} clip {:.3}",
                m.update,
                m.env_steps,
                self.total,
                m.approx_kl,
                m.clip_frac
            );
        }
    }

    /// Progress read from outside (the run directory of separate processes).
    pub fn position(&mut self, env_steps: u64, ret: Option<f64>, success: Option<f64>) {
        let ret = ret.map_or("-".into(), |r| format!("{r:.3}"));
        let success = success.map_or(String::new(), |s| format!(" success {s:.2}"));
        if let Some(bar) = &self.bar {
            bar.set_position(env_steps.min(self.total));
            bar.set_message(format!("return {ret}{success}"));
        } else if self.total > 0 && env_steps.saturating_sub(self.last_logged) >= self.total / 20 {
            self.last_logged = env_steps;
            tracing::info!("env_steps {env_steps}/{} return {ret}{success}", self.total);
        }
    }

    /// A message (pre-training done, evaluation started).
    pub fn note(&self, message: &str) {
        match &self.bar {
            Some(bar) => bar.println(message),
            None if self.total > 0 => tracing::info!("{message}"),
            None => {}
        }
    }

    /// A warning from one of the run's services: shown even when quiet.
    pub fn warn(&self, message: &str) {
        match &self.bar {
            Some(bar) => bar.println(message),
            None => tracing::warn!("{message}"),
        }
    }

    /// The run finished.
    pub fn finish(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }
}

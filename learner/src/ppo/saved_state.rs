//! What a learner's checkpoint carries besides the policy's weights (the snapshot's bytes,
//! which hold the observation normaliser's statistics too): the update count, the run's wall
//! seconds, the step accounts, the lag and drop counters, the newest embedding version, the
//! minibatch shuffler's position, the reward scaler's statistics and the optimisers' state
//! (the fused path's Adam moments and step; burn's optimiser record where that path runs) and
//! the exploration bonus's visit counts. A
//! learner that restores them updates exactly as the one that wrote them would have.
//!
//! Layout (`state_codec`): the magic `JSAELRN\0`, a format number, then the fields in the
//! order [`Learner::training_state`] writes them.

use burn::optim::AdamConfig;
use burn::tensor::Bytes;
use jsae_nn::AdamMoments;
use jsae_run_dir::LatestCheckpoint;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::credits::Account;
use super::state_codec::{StateError, StateReader, StateWriter};
use super::{ADAM_EPSILON, Adam, LagStats, Learner, LearnerError};
use crate::normalise::{RunningMeanStd, ScalerState};
use jsae_settings::UpdatePath;

/// The first bytes of a learner's training state.
const MAGIC: &[u8; 8] = b"JSAELRN\0";
/// The layout written below (1: before the visit counts, still read).
const FORMAT: u32 = 2;

/// A training state read back, whole, before any of it is applied.
#[derive(Debug)]
struct TrainingState {
    updates: u64,
    wall_seconds: f64,
    embedding_version: u64,
    dropped: (u64, u64),
    run_lag: LagStats,
    steps_before: u64,
    accounts: Vec<((u64, u64), Account)>,
    rng: ([u8; 32], u64, u128),
    scaler: Option<ScalerState>,
    adam: AdamMoments,
    burn_optimiser: Vec<u8>,
    visits: Vec<(u64, u32)>,
}

fn write_moments(w: &mut StateWriter, moments: &[Vec<f32>]) {
    w.u64(moments.len() as u64);
    for m in moments {
        w.f32s(m);
    }
}

fn read_moments(r: &mut StateReader<'_>, what: &str) -> Result<Vec<Vec<f32>>, StateError> {
    let n = r.count(8, what)?;
    (0..n).map(|_| r.f32s(what)).collect()
}

impl TrainingState {
    fn read(bytes: &[u8]) -> Result<Self, StateError> {
        let mut r = StateReader::new(bytes);
        let magic = r.u64("magic")?.to_le_bytes();
        if &magic != MAGIC {
            return Err(StateError("not a learner's training state".into()));
        }
        let format = r.u32("format")?;
        if !(1..=FORMAT).contains(&format) {
            return Err(StateError(format!(
                "format {format}; this build reads format {FORMAT}"
            )));
        }
        let updates = r.u64("updates")?;
        let wall_seconds = r.f64("wall seconds")?;
        let embedding_version = r.u64("embedding version")?;
        let dropped = (r.u64("dropped for lag")?, r.u64("dropped for embedding")?);
        let run_lag = LagStats {
            sum: r.u64("lag sum")?,
            count: r.u64("lag count")?,
            max: r.u64("lag max")?,
        };
        let steps_before = r.u64("steps before")?;
        let n = r.count(40, "accounts")?;
        let mut accounts = Vec::with_capacity(n);
        for _ in 0..n {
            let key = (r.u64("actor id")?, r.u64("incarnation")?);
            let account = Account {
                claimed: r.u64("claimed")?,
                credited: r.u64("credited")?,
                delivered: r.u64("delivered")?,
            };
            accounts.push((key, account));
        }
        let seed: [u8; 32] = r
            .bytes("shuffler seed")?
            .try_into()
            .map_err(|_| StateError("shuffler seed: not 32 bytes".into()))?;
        let rng = (
            seed,
            r.u64("shuffler stream")?,
            r.u128("shuffler position")?,
        );
        let scaler = match r.u32("reward scaler")? {
            0 => None,
            _ => {
                let stats = RunningMeanStd {
                    mean: r.f64("return mean")?,
                    var: r.f64("return variance")?,
                    count: r.f64("return count")?,
                };
                let n = r.count(20, "running returns")?;
                let mut returns = Vec::with_capacity(n);
                for _ in 0..n {
                    let stream = (r.u64("stream actor")?, r.u32("stream environment")?);
                    returns.push((stream, r.f64("running return")?));
                }
                Some(ScalerState { stats, returns })
            }
        };
        let adam = AdamMoments {
            time: r.u32("Adam step")? as i32,
            moment_1: read_moments(&mut r, "Adam first moments")?,
            moment_2: read_moments(&mut r, "Adam second moments")?,
        };
        let burn_optimiser = r.bytes("burn optimiser")?;
        let mut visits = Vec::new();
        if format >= 2 {
            let n = r.count(12, "visit counts")?;
            visits.reserve(n);
            for _ in 0..n {
                visits.push((r.u64("visited state")?, r.u32("visits")?));
            }
        }
        r.end()?;
        Ok(Self {
            updates,
            wall_seconds,
            embedding_version,
            dropped,
            run_lag,
            steps_before,
            accounts,
            rng,
            scaler,
            adam,
            burn_optimiser,
            visits,
        })
    }
}

impl Learner {
    /// This learner's latest checkpoint: the policy snapshot's version and bytes, and its
    /// training state at `wall_seconds` of the run.
    pub fn checkpoint(&self, wall_seconds: f64) -> Result<LatestCheckpoint, LearnerError> {
        let snapshot = self.snapshot()?;
        Ok(LatestCheckpoint {
            version: snapshot.version,
            weights: snapshot.bytes,
            state: self.training_state(wall_seconds)?,
        })
    }

    /// Goes on from a checkpoint: the weights and version (as [`Self::restore`]) and, where
    /// it carries a training state, everything else a checkpoint holds; returns the run's
    /// wall seconds at the checkpoint (None where it carries no state: then the optimiser
    /// and the counters start afresh). A state that does not read is refused before anything
    /// changes.
    pub fn resume(&mut self, checkpoint: &LatestCheckpoint) -> Result<Option<f64>, LearnerError> {
        let state = match checkpoint.state.is_empty() {
            true => None,
            false => Some(TrainingState::read(&checkpoint.state)?),
        };
        let burn_optimiser = match &state {
            Some(s) if !s.burn_optimiser.is_empty() => Some(
                AdamConfig::new()
                    .with_epsilon(ADAM_EPSILON)
                    .init()
                    .from_bytes(Bytes::from_bytes_vec(s.burn_optimiser.clone()))
                    .map_err(|e| StateError(format!("burn optimiser: {e}")))?,
            ),
            _ => None,
        };
        self.restore(&jsae_wire::PolicySnapshot {
            version: checkpoint.version,
            bytes: checkpoint.weights.clone(),
        })?;
        let Some(s) = state else {
            return Ok(None);
        };
        self.updates = s.updates;
        self.embedding_version = s.embedding_version;
        (self.dropped_lag, self.dropped_embedding) = s.dropped;
        self.run_lag = s.run_lag;
        self.credits.restore(s.steps_before, s.accounts);
        let (seed, stream, position) = s.rng;
        self.rng = ChaCha8Rng::from_seed(seed);
        self.rng.set_stream(stream);
        self.rng.set_word_pos(position);
        if let (Some(scaler), Some(saved)) = (self.reward_scaler.as_mut(), s.scaler) {
            scaler.set_state(saved);
        }
        self.fused.set_adam_moments(s.adam);
        if let Some(optim) = burn_optimiser {
            self.optim = Adam(optim);
        }
        if let Some(visits) = self.visits.as_mut() {
            visits.restore(&s.visits);
        }
        Ok(Some(s.wall_seconds))
    }

    /// The training state's bytes at `wall_seconds` of the run, for a checkpoint beside the
    /// snapshot's weights ([`Self::checkpoint`] takes both).
    pub fn training_state(&self, wall_seconds: f64) -> Result<Vec<u8>, LearnerError> {
        let mut w = StateWriter::default();
        w.u64(u64::from_le_bytes(*MAGIC));
        w.u32(FORMAT);
        w.u64(self.updates);
        w.f64(wall_seconds);
        w.u64(self.embedding_version);
        w.u64(self.dropped_lag);
        w.u64(self.dropped_embedding);
        w.u64(self.run_lag.sum);
        w.u64(self.run_lag.count);
        w.u64(self.run_lag.max);
        w.u64(self.credits.before());
        let mut accounts: Vec<_> = self.credits.accounts().collect();
        accounts.sort_by_key(|&(key, _)| key);
        w.u64(accounts.len() as u64);
        for ((actor, incarnation), a) in accounts {
            for v in [actor, incarnation, a.claimed, a.credited, a.delivered] {
                w.u64(v);
            }
        }
        w.bytes(&self.rng.get_seed());
        w.u64(self.rng.get_stream());
        w.u128(self.rng.get_word_pos());
        match &self.reward_scaler {
            None => w.u32(0),
            Some(scaler) => {
                let s = scaler.state();
                w.u32(1);
                w.f64(s.stats.mean);
                w.f64(s.stats.var);
                w.f64(s.stats.count);
                w.u64(s.returns.len() as u64);
                for ((actor, env), ret) in s.returns {
                    w.u64(actor);
                    w.u32(env);
                    w.f64(ret);
                }
            }
        }
        let adam = self.fused.adam_moments();
        w.u32(adam.time as u32);
        write_moments(&mut w, &adam.moment_1);
        write_moments(&mut w, &adam.moment_2);
        let burn_optimiser = match self.config.update {
            UpdatePath::Burn => self
                .optim
                .0
                .into_bytes()
                .map_err(|e| jsae_nn::RecordError(format!("burn optimiser: {e}")))?
                .to_vec(),
            UpdatePath::Fused => Vec::new(),
        };
        w.bytes(&burn_optimiser);
        let visits = self.visits.as_ref().map(|v| v.counts()).unwrap_or_default();
        w.u64(visits.len() as u64);
        for (key, n) in visits {
            w.u64(key);
            w.u32(n);
        }
        Ok(w.finish())
    }
}

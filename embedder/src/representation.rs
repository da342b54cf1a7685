//! The seam between the embedder's trainer and the model it trains. The trainer (replay
//! buffer, pre-training, continuous updates, versions, checkpoints) is the same for every
//! representation; what differs (the networks, their losses, their weights' bytes) sits
//! behind [`RepresentationModel`]. [`EmbeddingModel`] implements it for JSAE's phi/g/T/f and,
//! with other heads and losses, for the AE and RA baselines. Which questions a
//! representation answers for the rest of the system (does it embed states? does f decode
//! actions?) is `jsae_settings::Representation`.

use burn::optim::{GradientsParams, ModuleOptimizer};
use jsae_nn::RecordError;
use jsae_settings::Representation;
use jsae_wire::{ActionSpace, StateBatch, StateSpace};

use jsae_agent::EmbeddingModel;

use crate::EmbeddingTraining;
use crate::catalogue::CatalogueTables;
use crate::replay::Minibatch;

/// What the next-item loss is taken against, per state.
#[derive(Debug, Clone, Copy)]
pub enum NextItemTargets<'a> {
    /// The item bought after each state.
    Bought(&'a [u32]),
    /// A distribution over the items after each state, `[states, n]` row-major.
    Estimate(&'a [f32]),
}

/// A model the embedder trains from transitions and publishes as snapshots.
pub trait RepresentationModel: std::fmt::Debug + Send {
    /// The state space it takes.
    fn state_space(&self) -> &StateSpace;
    /// The action space it takes.
    fn action_space(&self) -> &ActionSpace;
    /// Updates input statistics (state normalisation) with new states.
    fn observe_states(&mut self, states: &StateBatch);
    /// One optimiser step on a minibatch at learning rate `lr`; returns (model loss, decoder
    /// loss) before the step (JSAE: `-log P(s'|s,a)` and f's; AE: the state and the action
    /// reconstruction; RA: `-log f(a | e(s, s'))` and 0).
    fn train_step(&mut self, optim: &mut ModuleOptimizer, mb: &Minibatch, lr: f64) -> (f32, f32);
    /// One optimiser step on the next-item loss alone (logged purchases: the item bought
    /// after each row of `states`, or a distribution over the items); the loss before the
    /// step, None for a model without the next-item head (nothing trained).
    fn train_next_item_step(
        &mut self,
        _optim: &mut ModuleOptimizer,
        _states: &StateBatch,
        _targets: NextItemTargets<'_>,
        _lr: f64,
    ) -> Option<f32> {
        None
    }
    /// (model loss, decoder loss) on a minibatch, without training.
    fn evaluate(&self, mb: &Minibatch) -> (f32, f32);
    /// The weights, as inference-side snapshot bytes.
    fn snapshot_bytes(&self) -> Result<Vec<u8>, RecordError>;
    /// Loads weights from snapshot bytes.
    fn load_bytes(&mut self, bytes: &[u8]) -> Result<(), RecordError>;
    /// Every discrete action's embedding, `[n, d]` row-major, and `d` (None for continuous
    /// actions).
    fn action_embeddings(&self) -> Option<(Vec<f32>, usize)>;
}

impl RepresentationModel for EmbeddingModel {
    fn state_space(&self) -> &StateSpace {
        EmbeddingModel::state_space(self)
    }

    fn action_space(&self) -> &ActionSpace {
        EmbeddingModel::action_space(self)
    }

    fn observe_states(&mut self, states: &StateBatch) {
        self.update_state_stats(states);
    }

    /// Every representation's losses (`EmbeddingModel::losses`), summed, one joint step.
    fn train_step(&mut self, optim: &mut ModuleOptimizer, mb: &Minibatch, lr: f64) -> (f32, f32) {
        let (model_loss, decoder_loss) = self.losses(&mb.states, &mb.actions, &mb.next_states);
        let total = model_loss.clone() + decoder_loss.clone();
        let grads = GradientsParams::from_grads(total.backward(), self.net());
        let net = optim.step(lr, self.net().clone(), grads);
        self.set_net(net);
        (
            model_loss.into_scalar::<f32>(),
            decoder_loss.into_scalar::<f32>(),
        )
    }

    fn train_next_item_step(
        &mut self,
        optim: &mut ModuleOptimizer,
        states: &StateBatch,
        targets: NextItemTargets<'_>,
        lr: f64,
    ) -> Option<f32> {
        let loss = match targets {
            NextItemTargets::Bought(items) => self.next_item_loss(states, items)?,
            NextItemTargets::Estimate(probs) => self.next_item_soft_loss(states, probs)?,
        };
        let grads = GradientsParams::from_grads(loss.backward(), self.net());
        let net = optim.step(lr, self.net().clone(), grads);
        self.set_net(net);
        Some(loss.into_scalar::<f32>())
    }

    fn evaluate(&self, mb: &Minibatch) -> (f32, f32) {
        let valid = self.for_inference(&self.device().clone().inner());
        let (a, b) = valid.losses(&mb.states, &mb.actions, &mb.next_states);
        (a.into_scalar::<f32>(), b.into_scalar::<f32>())
    }

    fn snapshot_bytes(&self) -> Result<Vec<u8>, RecordError> {
        self.for_inference(&self.device().clone().inner())
            .to_bytes()
    }

    fn load_bytes(&mut self, bytes: &[u8]) -> Result<(), RecordError> {
        EmbeddingModel::load_bytes(self, bytes)
    }

    fn action_embeddings(&self) -> Option<(Vec<f32>, usize)> {
        let table = self.action_table()?;
        Some((jsae_nn::to_vec(table), self.config().action_dim))
    }
}

/// The embedding model as the embedder trains it: the model, and at catalogue scale
/// (`embedding.sampled_softmax_from`) its item-sized tables on the host, which its steps,
/// evaluations and snapshots go through ([`CatalogueTables`]). It reads as the model.
#[derive(Debug)]
pub struct TrainingModel {
    model: EmbeddingModel,
    catalogue: Option<Box<CatalogueTables>>,
}

impl TrainingModel {
    /// `model` for training; at catalogue scale its tables copied to the host (T's output
    /// rows drawn from `seed`).
    pub fn new(model: EmbeddingModel, seed: u64) -> Self {
        // the model was built for it: JSAE's, categorical states, no T of its own
        let jsae = matches!(
            model.representation(),
            Representation::Jsae | Representation::Raw
        );
        let catalogue = (jsae
            && model.net().transition.is_none()
            && model
                .config()
                .samples_items(model.state_space(), model.action_space()))
        .then(|| CatalogueTables::new(&model, seed).ok())
        .flatten()
        .map(Box::new);
        Self { model, catalogue }
    }

    /// Whether it trains at catalogue scale.
    pub fn at_catalogue_scale(&self) -> bool {
        self.catalogue.is_some()
    }

    /// Takes the host tables from the model again (after its weights changed in place: a
    /// warm start).
    pub fn tables_from_model(&mut self) {
        if let Some(c) = &mut self.catalogue {
            c.read_from(&self.model);
        }
    }

    /// The model as a snapshot carries it (phi's and g's tables from the host).
    fn current(&self) -> std::borrow::Cow<'_, EmbeddingModel> {
        match &self.catalogue {
            Some(c) => std::borrow::Cow::Owned(c.write_into(&self.model)),
            None => std::borrow::Cow::Borrowed(&self.model),
        }
    }
}

impl std::ops::Deref for TrainingModel {
    type Target = EmbeddingModel;

    fn deref(&self) -> &EmbeddingModel {
        &self.model
    }
}

impl std::ops::DerefMut for TrainingModel {
    fn deref_mut(&mut self) -> &mut EmbeddingModel {
        &mut self.model
    }
}

impl RepresentationModel for TrainingModel {
    fn state_space(&self) -> &StateSpace {
        self.model.state_space()
    }

    fn action_space(&self) -> &ActionSpace {
        self.model.action_space()
    }

    fn observe_states(&mut self, states: &StateBatch) {
        self.model.observe_states(states);
    }

    fn train_step(&mut self, optim: &mut ModuleOptimizer, mb: &Minibatch, lr: f64) -> (f32, f32) {
        match &mut self.catalogue {
            Some(c) => {
                let loss = c.train_step(
                    &mut self.model,
                    optim,
                    &mb.states,
                    &mb.actions,
                    &mb.next_states,
                    lr,
                );
                (loss, 0.0)
            }
            None => self.model.train_step(optim, mb, lr),
        }
    }

    fn train_next_item_step(
        &mut self,
        optim: &mut ModuleOptimizer,
        states: &StateBatch,
        targets: NextItemTargets<'_>,
        lr: f64,
    ) -> Option<f32> {
        match (&mut self.catalogue, targets) {
            (Some(c), NextItemTargets::Bought(items)) => {
                self.model.net().next_item.as_ref()?;
                Some(c.next_item_step(&mut self.model, optim, states, items, lr))
            }
            // a distribution over a million items per state is not built (refused by the
            // settings at catalogue scale)
            (Some(_), NextItemTargets::Estimate(_)) => None,
            (None, targets) => self.model.train_next_item_step(optim, states, targets, lr),
        }
    }

    fn evaluate(&self, mb: &Minibatch) -> (f32, f32) {
        match &self.catalogue {
            Some(c) => (
                c.evaluate(&self.model, &mb.states, &mb.actions, &mb.next_states),
                0.0,
            ),
            None => self.model.evaluate(mb),
        }
    }

    fn snapshot_bytes(&self) -> Result<Vec<u8>, RecordError> {
        self.current().snapshot_bytes()
    }

    fn load_bytes(&mut self, bytes: &[u8]) -> Result<(), RecordError> {
        RepresentationModel::load_bytes(&mut self.model, bytes)?;
        self.tables_from_model();
        Ok(())
    }

    fn action_embeddings(&self) -> Option<(Vec<f32>, usize)> {
        match &self.catalogue {
            Some(c) => Some(c.action_embeddings()),
            None => self.model.action_embeddings(),
        }
    }
}

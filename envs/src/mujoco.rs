//! HalfCheetah and Ant on MuJoCo 3.17 (through mujoco-rs), step for step as Gymnasium's
//! HalfCheetah-v5 and Ant-v5 with default arguments: the same XML (embedded at build time from
//! the gymnasium wheel, see scripts/setup-mujoco.sh), the same calls into MuJoCo in the same
//! order, the same observation, reward terms, health check, frame skip (5), reset noise
//! distribution and 1000-step truncation.
//!
//! A step: `ctrl = action` (not clipped: MuJoCo clamps to the actuators' ctrlrange, the
//! control cost uses the action as given), `mj_step` five times, then `mj_rnePostConstraint`
//! (for Ant's contact forces; HalfCheetah's outputs do not read them, so it skips the call).
//! A reset: `mj_resetData`, `qpos = qpos0 + U(-0.1, 0.1)`, `qvel = 0.1 N(0, 1)`, `mj_forward`.

use std::sync::{Arc, OnceLock};

use jsae_env_spec::MujocoConfig;
use jsae_spaces::{ActionSpace, StateBatch, StateSpace};
use mujoco_rs::prelude::{MjData, MjModel};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use super::{ActionRef, Env, Step};

/// Gymnasium's `frame_skip` for both robots.
pub const FRAME_SKIP: usize = 5;
const RESET_NOISE: f64 = 0.1;

const HALF_CHEETAH_XML: &str = include_str!(concat!(
    env!("MUJOCO_DYNAMIC_LINK_DIR"),
    "/assets/half_cheetah.xml"
));
const ANT_XML: &str = include_str!(concat!(env!("MUJOCO_DYNAMIC_LINK_DIR"), "/assets/ant.xml"));

/// Which robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Robot {
    /// HalfCheetah-v5.
    HalfCheetah,
    /// Ant-v5.
    Ant,
}

impl Robot {
    /// The compiled model, parsed once per process and shared by every environment.
    pub fn model(self) -> Arc<MjModel> {
        static CHEETAH: OnceLock<Arc<MjModel>> = OnceLock::new();
        static ANT: OnceLock<Arc<MjModel>> = OnceLock::new();
        let (cell, xml) = match self {
            Self::HalfCheetah => (&CHEETAH, HALF_CHEETAH_XML),
            Self::Ant => (&ANT, ANT_XML),
        };
        configure_logging();
        cell.get_or_init(|| {
            Arc::new(
                MjModel::from_xml_string(xml)
                    .unwrap_or_else(|e| panic!("the embedded {self:?} XML does not load: {e}")),
            )
        })
        .clone()
    }
}

/// MuJoCo's messages go to this program's log (tracing, target `mujoco`) instead of its
/// default console and `MUJOCO_LOG.TXT` output, all but one: half_cheetah.xml (Gymnasium's
/// HalfCheetah-v5 model, kept as it is for parity) uses the deprecated `settotalmass`, and
/// MuJoCo warns about it on every load, which says nothing a user can act on.
fn configure_logging() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // SAFETY: every MuJoCo object of this process is made through `Robot::model`, which
        // runs this first; `call_once` blocks every other caller until it returns, so no
        // thread uses MuJoCo while the handler is installed.
        #[allow(unsafe_code)]
        unsafe {
            mujoco_rs::logging::set_log_handler(log_mujoco_message);
            // the handler turns every info topic on (per-step timing among them): off again,
            // so MuJoCo formats no message where it has nothing to warn about
            let config = mujoco_rs::wrappers::mj_logging::log_config().with_topics(0);
            mujoco_rs::wrappers::mj_logging::set_log_config(config);
        };
    });
}

/// Whether a MuJoCo message is the known `settotalmass` deprecation warning.
fn is_settotalmass_warning(text: &str) -> bool {
    text.contains("settotalmass")
}

/// MuJoCo's log handler: its warnings and errors as tracing events; info and debug messages
/// are dropped unread. It runs across the C boundary, where a panic aborts the process, so
/// a panic inside (reading text that is not UTF-8) is caught and the message dropped.
fn log_mujoco_message(message: &mujoco_rs::wrappers::mj_logging::MjLogMessage) {
    use mujoco_rs::wrappers::mj_logging::MjtLogLevel;
    let level = message.level();
    if matches!(level, MjtLogLevel::mjLOG_INFO | MjtLogLevel::mjLOG_DEBUG) {
        return;
    }
    let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let subject = message.subject();
        let body = message.body().unwrap_or_default();
        if is_settotalmass_warning(subject) || is_settotalmass_warning(body) {
            return;
        }
        if level == MjtLogLevel::mjLOG_ERROR {
            tracing::error!(target: "mujoco", "{subject} {body}");
        } else {
            tracing::warn!(target: "mujoco", "{subject} {body}");
        }
    }));
}

/// Ant-v5's constants (Gymnasium defaults).
mod ant {
    pub const CTRL_COST: f64 = 0.5;
    pub const CONTACT_COST: f64 = 5e-4;
    pub const HEALTHY_REWARD: f64 = 1.0;
    pub const HEALTHY_Z: (f64, f64) = (0.2, 1.0);
    pub const CONTACT_FORCE: (f64, f64) = (-1.0, 1.0);
    pub const MAIN_BODY: usize = 1;
}

/// HalfCheetah-v5's constants (Gymnasium defaults).
mod cheetah {
    pub const FORWARD_REWARD: f64 = 1.0;
    pub const CTRL_COST: f64 = 0.1;
}

/// One MuJoCo environment.
pub struct MujocoEnv {
    robot: Robot,
    data: MjData<Arc<MjModel>>,
    init_qpos: Vec<f64>,
    init_qvel: Vec<f64>,
    dt: f64,
    max_steps: u32,
    steps: u32,
    ctrl: Vec<f64>,
    obs: Vec<f64>,
    state_space: StateSpace,
    action_space: ActionSpace,
}

impl std::fmt::Debug for MujocoEnv {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MujocoEnv")
            .field("robot", &self.robot)
            .field("steps", &self.steps)
            .finish()
    }
}

impl MujocoEnv {
    /// A new environment (call `reset` before stepping).
    pub fn new(robot: Robot, config: &MujocoConfig) -> Self {
        let model = robot.model();
        let data = MjData::new(model.clone());
        let raw = model.ffi();
        let (nq, nv, nu, nbody) = (
            raw.nq as usize,
            raw.nv as usize,
            raw.nu as usize,
            raw.nbody as usize,
        );
        let dim = match robot {
            Robot::HalfCheetah => nq - 1 + nv,
            Robot::Ant => nq - 2 + nv + 6 * (nbody - 1),
        };
        let (mut low, mut high) = (Vec::with_capacity(nu), Vec::with_capacity(nu));
        for range in model.actuator_ctrlrange() {
            low.push(range[0] as f32);
            high.push(range[1] as f32);
        }
        let mut env = Self {
            robot,
            init_qpos: data.qpos().to_vec(),
            init_qvel: data.qvel().to_vec(),
            dt: raw.opt.timestep * FRAME_SKIP as f64,
            data,
            max_steps: config.max_steps,
            steps: 0,
            ctrl: vec![0.0; nu],
            obs: Vec::with_capacity(dim),
            state_space: StateSpace::Real { dim },
            action_space: ActionSpace::Continuous { dim: nu, low, high },
        };
        env.observe();
        env
    }

    /// The robot.
    pub fn robot(&self) -> Robot {
        self.robot
    }

    /// Sizes of qpos and qvel.
    pub fn state_sizes(&self) -> (usize, usize) {
        (self.init_qpos.len(), self.init_qvel.len())
    }

    /// The current observation in double precision, as Gymnasium returns it.
    pub fn observation(&self) -> &[f64] {
        &self.obs
    }

    /// Gymnasium's reset with a given state: `mj_resetData`, set qpos and qvel, `mj_forward`.
    /// Panics if the lengths are not the model's nq and nv.
    pub fn reset_to(&mut self, qpos: &[f64], qvel: &[f64]) {
        self.data.reset();
        self.data.qpos_mut().copy_from_slice(qpos);
        self.data.qvel_mut().copy_from_slice(qvel);
        self.data.forward();
        self.steps = 0;
        self.observe();
    }

    /// One step with the action in double precision (what the parity check feeds).
    pub fn step_f64(&mut self, action: &[f64]) -> Step {
        let before = self.position();
        self.data.ctrl_mut().copy_from_slice(action);
        for _ in 0..FRAME_SKIP {
            self.data.step();
        }
        if self.robot == Robot::Ant {
            self.data.rne_post_constraint();
        }
        let after = self.position();
        let ctrl_sq: f64 = action.iter().map(|a| a * a).sum();
        let (reward, terminated) = match self.robot {
            Robot::HalfCheetah => {
                let x_velocity = (after[0] - before[0]) / self.dt;
                let forward = cheetah::FORWARD_REWARD * x_velocity;
                (forward - cheetah::CTRL_COST * ctrl_sq, false)
            }
            Robot::Ant => {
                let x_velocity = (after[0] - before[0]) / self.dt;
                let healthy = self.ant_is_healthy();
                let rewards = x_velocity + if healthy { ant::HEALTHY_REWARD } else { 0.0 };
                let costs = ant::CTRL_COST * ctrl_sq + ant::CONTACT_COST * self.contact_sq();
                (rewards - costs, !healthy)
            }
        };
        self.steps += 1;
        self.observe();
        Step {
            reward,
            terminated,
            truncated: !terminated && self.steps >= self.max_steps,
            success: false,
            lost: false,
        }
    }

    /// HalfCheetah: qpos[0]; Ant: the torso's (x, y) from xpos.
    fn position(&self) -> [f64; 2] {
        match self.robot {
            Robot::HalfCheetah => [self.data.qpos()[0], 0.0],
            Robot::Ant => {
                let p = self.data.xpos()[ant::MAIN_BODY];
                [p[0], p[1]]
            }
        }
    }

    fn ant_is_healthy(&self) -> bool {
        let (qpos, qvel) = (self.data.qpos(), self.data.qvel());
        let finite = qpos.iter().chain(qvel).all(|v| v.is_finite());
        finite && (ant::HEALTHY_Z.0..=ant::HEALTHY_Z.1).contains(&qpos[2])
    }

    /// Sum of squares of every body's clipped external contact force.
    fn contact_sq(&self) -> f64 {
        let (lo, hi) = ant::CONTACT_FORCE;
        self.data
            .cfrc_ext()
            .iter()
            .flatten()
            .map(|&f| {
                let c = f.clamp(lo, hi);
                c * c
            })
            .sum()
    }

    fn observe(&mut self) {
        self.obs.clear();
        let (qpos, qvel) = (self.data.qpos(), self.data.qvel());
        match self.robot {
            Robot::HalfCheetah => {
                self.obs.extend_from_slice(&qpos[1..]);
                self.obs.extend_from_slice(qvel);
            }
            Robot::Ant => {
                self.obs.extend_from_slice(&qpos[2..]);
                self.obs.extend_from_slice(qvel);
                let (lo, hi) = ant::CONTACT_FORCE;
                for body in &self.data.cfrc_ext()[1..] {
                    self.obs.extend(body.iter().map(|f| f.clamp(lo, hi)));
                }
            }
        }
    }
}

impl Env for MujocoEnv {
    fn state_space(&self) -> &StateSpace {
        &self.state_space
    }

    fn action_space(&self) -> &ActionSpace {
        &self.action_space
    }

    fn has_success(&self) -> bool {
        false
    }

    fn reset(&mut self, rng: &mut ChaCha8Rng) {
        let mut qpos = self.init_qpos.clone();
        for q in &mut qpos {
            *q += rng.random_range(-RESET_NOISE..RESET_NOISE);
        }
        let mut qvel = self.init_qvel.clone();
        for v in &mut qvel {
            *v += RESET_NOISE * rng.sample::<f64, _>(StandardNormal);
        }
        self.reset_to(&qpos, &qvel);
    }

    fn step(&mut self, action: ActionRef<'_>) -> Step {
        let mut ctrl = std::mem::take(&mut self.ctrl);
        match action {
            ActionRef::Continuous(a) => {
                for (c, &v) in ctrl.iter_mut().zip(a) {
                    *c = f64::from(v);
                }
            }
            ActionRef::Discrete(_) => panic!("MuJoCo environments take continuous actions"),
        }
        let step = self.step_f64(&ctrl);
        self.ctrl = ctrl;
        step
    }

    fn push_state(&self, out: &mut StateBatch) {
        if let StateBatch::Real { data, .. } = out {
            data.extend(self.obs.iter().map(|&v| v as f32));
        }
    }
}

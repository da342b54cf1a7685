//! The recommender: purchase sessions from three sources (REES46 CSV, the Instacart sample,
//! a seeded generator), the session store that `SubmitSessions` appends to, the n-gram MDP
//! built from them (Shani et al.), the environment over it, and the gRPC Recommender service.

pub mod baseline;
pub mod client;
pub mod data;
pub mod env;
pub mod instacart;
pub mod ngram;
pub mod rees46;
pub mod service;
pub mod sessions;
pub mod store;
pub mod synthetic;

pub use data::{ModelHandle, RecsysError, model_handle};
pub use env::RecommenderEnv;
pub use ngram::{Catalogue, NgramModel};
pub use sessions::{Purchase, Session};

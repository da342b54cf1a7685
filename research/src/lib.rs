//! Research examples, each a measurement one of the experiment pages reports (`examples/`):
//! nothing here is a library; the crate keeps them out of the service crates.

#![forbid(unsafe_code)]

//! Host <-> tensor conversion and weight snapshots as bytes.

use burn::module::Module;
use burn::store::ModuleRecord;
use burn::tensor::{Bytes, Device, Tensor, TensorData};

/// Why weights could not be turned into bytes or back.
#[derive(Debug, thiserror::Error)]
#[error("weight record: {0}")]
pub struct RecordError(pub String);

/// A `[rows, cols]` tensor from row-major values.
pub fn tensor2(values: Vec<f32>, rows: usize, cols: usize, device: &Device) -> Tensor<2> {
    Tensor::from_data(TensorData::new(values, [rows, cols]), device)
}

/// A `[len]` tensor.
pub fn tensor1(values: Vec<f32>, device: &Device) -> Tensor<1> {
    let len = values.len();
    Tensor::from_data(TensorData::new(values, [len]), device)
}

/// The values of a float tensor, row-major.
pub fn to_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .unwrap_or_default()
}

/// A module's weights as bytes (burnpack).
pub fn into_bytes<M: Module>(module: &M) -> Result<Vec<u8>, RecordError> {
    module
        .clone()
        .into_record()
        .into_bytes()
        .map(|b| b.to_vec())
        .map_err(|e| RecordError(e.to_string()))
}

/// Loads weights from bytes into a module of the same structure (checked on load).
pub fn from_bytes<M: Module>(module: M, bytes: &[u8]) -> Result<M, RecordError> {
    from_owned_bytes(module, bytes.to_vec())
}

/// [`from_bytes`] from bytes the caller gives up: no copy of them is made (a snapshot of a
/// million items' tables is hundreds of MB).
pub fn from_owned_bytes<M: Module>(module: M, bytes: Vec<u8>) -> Result<M, RecordError> {
    let record = ModuleRecord::from_bytes(Bytes::from_bytes_vec(bytes))
        .map_err(|e| RecordError(e.to_string()))?;
    module
        .try_load_record(record)
        .map_err(|e| RecordError(e.to_string()))
}

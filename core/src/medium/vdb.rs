//! OpenVDB files (placeholder).
use super::file::{GridFormatError, GridLimits, LoadedGrid};
/// A grid.
pub struct VdbGrid;
/// Reads.
pub fn read_vdb(_b: &[u8], _n: Option<&str>, _l: &GridLimits) -> Result<VdbGrid, GridFormatError> {
    Err(GridFormatError::Unsupported("x".into()))
}
impl VdbGrid {
    /// Converts.
    pub fn to_density(&self, _l: &GridLimits) -> Result<LoadedGrid, GridFormatError> {
        Err(GridFormatError::Unsupported("x".into()))
    }
}

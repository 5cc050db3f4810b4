//! Reading accessors into plain vectors with every byte range checked first, so malformed
//! files (offsets past the end, absurd counts, sparse indices out of range) give an error
//! instead of a panic or a huge allocation.

use super::Loader;
use gltf::accessor::{DataType, Dimensions};
use rayon::prelude::*;

/// Accessors without a buffer view (all zeros, possibly with sparse values) cost memory that no
/// file data backs, so their element count is capped.
const MAX_VIEWLESS_COUNT: usize = 1 << 24;

fn component_size(dt: DataType) -> usize {
    match dt {
        DataType::I8 | DataType::U8 => 1,
        DataType::I16 | DataType::U16 => 2,
        DataType::U32 | DataType::F32 => 4,
    }
}

fn component_count(d: Dimensions) -> usize {
    match d {
        Dimensions::Scalar => 1,
        Dimensions::Vec2 => 2,
        Dimensions::Vec3 => 3,
        Dimensions::Vec4 | Dimensions::Mat2 => 4,
        Dimensions::Mat3 => 9,
        Dimensions::Mat4 => 16,
    }
}

/// Converts one component to f32, applying the glTF normalisation rules.
fn to_f32(dt: DataType, normalized: bool, b: &[u8]) -> f32 {
    let g = |i: usize| b.get(i).copied().unwrap_or(0);
    match dt {
        DataType::F32 => f32::from_le_bytes([g(0), g(1), g(2), g(3)]),
        DataType::U8 if normalized => g(0) as f32 / 255.0,
        DataType::U8 => g(0) as f32,
        DataType::I8 if normalized => (g(0) as i8 as f32 / 127.0).max(-1.0),
        DataType::I8 => g(0) as i8 as f32,
        DataType::U16 if normalized => u16::from_le_bytes([g(0), g(1)]) as f32 / 65535.0,
        DataType::U16 => u16::from_le_bytes([g(0), g(1)]) as f32,
        DataType::I16 if normalized => {
            (i16::from_le_bytes([g(0), g(1)]) as f32 / 32767.0).max(-1.0)
        }
        DataType::I16 => i16::from_le_bytes([g(0), g(1)]) as f32,
        DataType::U32 => u32::from_le_bytes([g(0), g(1), g(2), g(3)]) as f32,
    }
}

fn to_u32(dt: DataType, b: &[u8]) -> u32 {
    let g = |i: usize| b.get(i).copied().unwrap_or(0);
    match dt {
        DataType::U8 | DataType::I8 => g(0) as u32,
        DataType::U16 | DataType::I16 => u16::from_le_bytes([g(0), g(1)]) as u32,
        DataType::U32 | DataType::F32 => u32::from_le_bytes([g(0), g(1), g(2), g(3)]),
    }
}

impl Loader<'_> {
    /// The bytes of buffer view `view`, checked against its buffer.
    pub(super) fn view_bytes(
        &self,
        view: &gltf::buffer::View,
        label: &str,
    ) -> Result<&[u8], String> {
        let b = view.buffer().index();
        let buf = self
            .buffers
            .get(b)
            .ok_or_else(|| format!("{label}: buffer {b} is missing"))?;
        let start = view.offset();
        start
            .checked_add(view.length())
            .and_then(|end| buf.get(start..end))
            .ok_or_else(|| {
                format!(
                    "{label}: buffer view {} (offset {start}, length {}) reads past the end of buffer {b} ({} bytes)",
                    view.index(),
                    view.length(),
                    buf.len()
                )
            })
    }

    /// Reads `accessor` as `count` elements of `N` components converted by `conv`, after
    /// checking that every byte it names lies inside its buffer view and buffer (`N` is the
    /// accessor's component count, checked by the caller). Decoded in parallel.
    fn read_with<T: Copy + Default + Send + Sync, const N: usize>(
        &mut self,
        accessor: &gltf::Accessor,
        label: &str,
        conv: impl Fn(DataType, bool, &[u8]) -> T + Sync,
    ) -> Result<Vec<[T; N]>, String> {
        let ai = accessor.index();
        let dt = accessor.data_type();
        let normalized = accessor.normalized();
        let csize = component_size(dt);
        let ncomp = component_count(accessor.dimensions());
        if ncomp != N {
            return Err(format!(
                "{label}: accessor {ai} has {ncomp} components, expected {N}"
            ));
        }
        let elem = csize * ncomp;
        // One element from its bytes (`elem` of them).
        let element = |b: &[u8]| -> [T; N] {
            std::array::from_fn(|c| conv(dt, normalized, b.get(c * csize..).unwrap_or(&[])))
        };
        let count = accessor.count();
        let values = count
            .checked_mul(ncomp)
            .ok_or_else(|| format!("{label}: accessor {ai} count {count} is absurd"))?;

        let mut out: Vec<[T; N]>;
        match accessor.view() {
            Some(view) => {
                let bytes = self.view_bytes(&view, label)?;
                let stride = view.stride().unwrap_or(elem);
                if stride < elem {
                    return Err(format!(
                        "{label}: accessor {ai}: byteStride {stride} of buffer view {} is smaller than an element ({elem} bytes)",
                        view.index()
                    ));
                }
                let start = accessor.offset();
                let needed = if count == 0 {
                    Some(start)
                } else {
                    (count - 1)
                        .checked_mul(stride)
                        .and_then(|n| n.checked_add(elem))
                        .and_then(|n| n.checked_add(start))
                };
                match needed {
                    Some(n) if n <= bytes.len() => {}
                    _ => {
                        return Err(format!(
                            "{label}: accessor {ai} ({count} elements from offset {start}, stride {stride}) reads past the end of buffer view {} ({} bytes) of buffer {}",
                            view.index(),
                            bytes.len(),
                            view.buffer().index()
                        ))
                    }
                }
                self.charge(values.saturating_mul(std::mem::size_of::<T>()), label)?;
                // Every element lies inside `bytes` (checked just above).
                out = (0..count)
                    .into_par_iter()
                    .with_min_len(1 << 12)
                    .map(|i| {
                        let at = start + i * stride;
                        bytes.get(at..at + elem).map_or([T::default(); N], element)
                    })
                    .collect();
            }
            None => {
                // All zeros (glTF 2.0, 3.6.2.1), with the sparse values below if it has any.
                if count > MAX_VIEWLESS_COUNT {
                    return Err(format!(
                        "{label}: accessor {ai} without a buffer view claims {count} elements (at most {MAX_VIEWLESS_COUNT})"
                    ));
                }
                self.charge(values.saturating_mul(std::mem::size_of::<T>()), label)?;
                out = vec![[T::default(); N]; count];
            }
        }

        if let Some(sparse) = accessor.sparse() {
            let scount = sparse.count();
            if scount > count {
                return Err(format!(
                    "{label}: accessor {ai}: sparse count {scount} exceeds the accessor count {count}"
                ));
            }
            let indices = sparse.indices();
            let idt = match indices.index_type() {
                gltf::accessor::sparse::IndexType::U8 => DataType::U8,
                gltf::accessor::sparse::IndexType::U16 => DataType::U16,
                gltf::accessor::sparse::IndexType::U32 => DataType::U32,
            };
            let isize = component_size(idt);
            let ibytes = self.view_bytes(&indices.view(), label)?;
            let ioff = indices.offset();
            let ibytes = scount
                .checked_mul(isize)
                .and_then(|n| n.checked_add(ioff))
                .and_then(|end| ibytes.get(ioff..end))
                .ok_or_else(|| {
                    format!("{label}: accessor {ai}: sparse indices read past the end of buffer view {}", indices.view().index())
                })?;
            let vals = sparse.values();
            let vbytes = self.view_bytes(&vals.view(), label)?;
            let voff = vals.offset();
            let vbytes = scount
                .checked_mul(elem)
                .and_then(|n| n.checked_add(voff))
                .and_then(|end| vbytes.get(voff..end))
                .ok_or_else(|| {
                    format!(
                        "{label}: accessor {ai}: sparse values read past the end of buffer view {}",
                        vals.view().index()
                    )
                })?;
            let mut previous = None;
            for s in 0..scount {
                let ib = ibytes.get(s * isize..(s + 1) * isize).unwrap_or(&[]);
                let target = to_u32(idt, ib) as usize;
                if target >= count {
                    return Err(format!(
                        "{label}: accessor {ai}: sparse index {target} is out of range ({count} elements)"
                    ));
                }
                // The specification requires it; an index given twice would leave the element
                // to whichever value a reader takes last.
                if let Some(p) = previous.filter(|&p| target <= p) {
                    return Err(format!(
                        "{label}: accessor {ai}: sparse indices must strictly increase, \
                         got {target} after {p}"
                    ));
                }
                previous = Some(target);
                if let Some(slot) = out.get_mut(target) {
                    *slot = element(vbytes.get(s * elem..).unwrap_or(&[]));
                }
            }
        }
        Ok(out)
    }

    /// Reads a float (or normalised integer) attribute with the expected dimensions (`N`
    /// components).
    pub(super) fn read_floats<const N: usize>(
        &mut self,
        accessor: &gltf::Accessor,
        label: &str,
        expected: Dimensions,
    ) -> Result<Vec<[f32; N]>, String> {
        if accessor.dimensions() != expected {
            return Err(format!(
                "{label}: accessor {} is {:?}, expected {expected:?}",
                accessor.index(),
                accessor.dimensions()
            ));
        }
        let v = self.read_with::<f32, N>(accessor, label, to_f32)?;
        let finite = |e: &[f32; N]| e.iter().all(|x| x.is_finite());
        if let Some(i) = v.par_iter().position_first(|e| !finite(e)) {
            return Err(format!(
                "{label}: accessor {} element {i} is not finite (NaN or infinite)",
                accessor.index(),
            ));
        }
        Ok(v)
    }

    /// Reads an index accessor (unsigned 8, 16 or 32-bit scalars).
    pub(super) fn read_indices(
        &mut self,
        accessor: &gltf::Accessor,
        label: &str,
    ) -> Result<Vec<u32>, String> {
        let dt = accessor.data_type();
        if accessor.dimensions() != Dimensions::Scalar
            || !matches!(dt, DataType::U8 | DataType::U16 | DataType::U32)
        {
            return Err(format!(
                "{label}: index accessor {} must hold unsigned 8, 16 or 32-bit scalars",
                accessor.index()
            ));
        }
        let v = self.read_with::<u32, 1>(accessor, label, |dt, _, b| to_u32(dt, b))?;
        Ok(v.into_iter().map(|[i]| i).collect())
    }
}

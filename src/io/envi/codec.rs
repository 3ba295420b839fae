//! Conversion between raw ENVI values and `f32`, strided so one routine serves every
//! interleave. No function here can panic: lengths are handled by zipping iterators.

use super::{ByteOrder, DataType};

/// How one band row sits in a raw buffer: value index of its first sample and the
/// distance, in values, between consecutive samples (1 for `bsq`/`bil`, `bands` for `bip`).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Layout {
    pub first: usize,
    pub stride: usize,
}

fn array<const N: usize>(chunk: &[u8]) -> [u8; N] {
    chunk.try_into().unwrap_or([0; N])
}

/// Decodes the values of one band row from `raw` into `out`, dividing integers by `scale`
/// when given.
pub(crate) fn decode(
    raw: &[u8],
    data_type: DataType,
    order: ByteOrder,
    layout: Layout,
    scale: Option<f64>,
    out: &mut [f32],
) {
    if layout.stride <= 1 && scale.is_none() {
        // Consecutive values without a scale (`bsq` and `bil` rows): one loop per type and
        // byte order, which the compiler vectorises.
        let at = layout
            .first
            .saturating_mul(data_type.bytes())
            .min(raw.len());
        let raw = &raw[at..];
        let big = order == ByteOrder::Big;
        match (data_type, big) {
            (DataType::F32, false) => {
                for (o, c) in out.iter_mut().zip(raw.chunks_exact(4)) {
                    *o = f32::from_le_bytes(array::<4>(c));
                }
                return;
            }
            (DataType::U16, false) => {
                for (o, c) in out.iter_mut().zip(raw.chunks_exact(2)) {
                    *o = f32::from(u16::from_le_bytes(array::<2>(c)));
                }
                return;
            }
            (DataType::U16, true) => {
                for (o, c) in out.iter_mut().zip(raw.chunks_exact(2)) {
                    *o = f32::from(u16::from_be_bytes(array::<2>(c)));
                }
                return;
            }
            _ => {}
        }
    }
    let values = raw
        .chunks_exact(data_type.bytes())
        .skip(layout.first)
        .step_by(layout.stride.max(1));
    let big = order == ByteOrder::Big;
    let int = |v: f32| match scale {
        Some(s) => (f64::from(v) / s) as f32,
        None => v,
    };
    match data_type {
        DataType::F32 => {
            for (o, c) in out.iter_mut().zip(values) {
                let b = array::<4>(c);
                *o = if big {
                    f32::from_be_bytes(b)
                } else {
                    f32::from_le_bytes(b)
                };
            }
        }
        DataType::F64 => {
            for (o, c) in out.iter_mut().zip(values) {
                let b = array::<8>(c);
                *o = if big {
                    f64::from_be_bytes(b)
                } else {
                    f64::from_le_bytes(b)
                } as f32;
            }
        }
        DataType::U16 => {
            for (o, c) in out.iter_mut().zip(values) {
                let b = array::<2>(c);
                let v = if big {
                    u16::from_be_bytes(b)
                } else {
                    u16::from_le_bytes(b)
                };
                *o = int(f32::from(v));
            }
        }
        DataType::I16 => {
            for (o, c) in out.iter_mut().zip(values) {
                let b = array::<2>(c);
                let v = if big {
                    i16::from_be_bytes(b)
                } else {
                    i16::from_le_bytes(b)
                };
                *o = int(f32::from(v));
            }
        }
    }
}

/// Encodes one band row into `raw` at `layout`. Integer types multiply by `scale` when
/// given, then round to nearest and clamp to the type's range (NaN becomes 0).
/// Float64 and int16 are encoded too, although the writer only offers float32 and uint16.
pub(crate) fn encode(
    values: &[f32],
    data_type: DataType,
    order: ByteOrder,
    layout: Layout,
    scale: Option<f64>,
    raw: &mut [u8],
) {
    let big = order == ByteOrder::Big;
    if layout.first == 0 && layout.stride <= 1 && scale.is_none() {
        // Consecutive values without a scale (what the writers' BSQ and BIL rows are):
        // one loop per type and byte order.
        match (data_type, big) {
            (DataType::F32, false) => {
                for (slot, &v) in raw.chunks_exact_mut(4).zip(values) {
                    slot.copy_from_slice(&v.to_le_bytes());
                }
                return;
            }
            (DataType::F32, true) => {
                for (slot, &v) in raw.chunks_exact_mut(4).zip(values) {
                    slot.copy_from_slice(&v.to_be_bytes());
                }
                return;
            }
            (DataType::U16, _) => {
                for (slot, &v) in raw.chunks_exact_mut(2).zip(values) {
                    // `v.round() as u16` without a library call: `v + 0.5` is exact in
                    // f64 for any f32 `v`, its truncation is the rounding of a
                    // non-negative `v`, and `as` saturates (negatives and NaN to 0).
                    let x = (f64::from(v) + 0.5).max(0.0) as u16;
                    slot.copy_from_slice(&if big {
                        x.to_be_bytes()
                    } else {
                        x.to_le_bytes()
                    });
                }
                return;
            }
            _ => {}
        }
    }
    let slots = raw
        .chunks_exact_mut(data_type.bytes())
        .skip(layout.first)
        .step_by(layout.stride.max(1));
    let int = |v: f32| {
        let v = f64::from(v);
        match scale {
            Some(s) => (v * s).round(),
            None => v.round(),
        }
    };
    for (slot, &v) in slots.zip(values) {
        match data_type {
            DataType::F32 => {
                let b = if big {
                    v.to_be_bytes()
                } else {
                    v.to_le_bytes()
                };
                slot.copy_from_slice(&b);
            }
            DataType::F64 => {
                let v = f64::from(v);
                let b = if big {
                    v.to_be_bytes()
                } else {
                    v.to_le_bytes()
                };
                slot.copy_from_slice(&b);
            }
            DataType::U16 => {
                // `as` saturates at the type's bounds and maps NaN to 0.
                let v = int(v) as u16;
                let b = if big {
                    v.to_be_bytes()
                } else {
                    v.to_le_bytes()
                };
                slot.copy_from_slice(&b);
            }
            DataType::I16 => {
                let v = int(v) as i16;
                let b = if big {
                    v.to_be_bytes()
                } else {
                    v.to_le_bytes()
                };
                slot.copy_from_slice(&b);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_type_and_order_round_trips_strided() {
        let values = [0.0f32, 1.0, 2.0, 65535.0];
        for dt in [DataType::I16, DataType::U16, DataType::F32, DataType::F64] {
            for order in [ByteOrder::Little, ByteOrder::Big] {
                let layout = Layout {
                    first: 1,
                    stride: 3,
                };
                let mut raw = vec![0u8; 12 * dt.bytes()];
                encode(&values, dt, order, layout, None, &mut raw);
                let mut back = [9.0f32; 4];
                decode(&raw, dt, order, layout, None, &mut back);
                let want = if dt == DataType::I16 {
                    [0.0, 1.0, 2.0, 32767.0]
                } else {
                    values
                };
                assert_eq!(back, want, "{dt:?} {order:?}");
            }
        }
    }

    #[test]
    fn integers_round_clamp_and_scale() {
        let layout = Layout {
            first: 0,
            stride: 1,
        };
        let mut raw = [0u8; 10];
        encode(
            &[-5.0, 1.4, 1.6, f32::NAN, 1e9],
            DataType::U16,
            ByteOrder::Little,
            layout,
            None,
            &mut raw,
        );
        let mut back = [0.0f32; 5];
        decode(
            &raw,
            DataType::U16,
            ByteOrder::Little,
            layout,
            None,
            &mut back,
        );
        assert_eq!(back, [0.0, 1.0, 2.0, 0.0, 65535.0]);
        encode(
            &[0.5],
            DataType::U16,
            ByteOrder::Big,
            layout,
            Some(1000.0),
            &mut raw,
        );
        assert_eq!(&raw[..2], &500u16.to_be_bytes());
        decode(
            &raw[..2],
            DataType::U16,
            ByteOrder::Big,
            layout,
            Some(1000.0),
            &mut back[..1],
        );
        assert_eq!(back[0], 0.5);
    }
}

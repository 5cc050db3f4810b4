//! Tests for every BSDF.

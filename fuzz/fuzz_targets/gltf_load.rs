//! Feeds arbitrary bytes to the glTF loader as an in-memory .gltf/.glb (external URIs refused).
//! Any panic, abort or out-of-memory is a bug: hostile files must give an error.
#![no_main]

use libfuzzer_sys::fuzz_target;
use raytile_core::scene::gltf::{load_gltf_slice, GltfOptions};

fuzz_target!(|data: &[u8]| {
    let opts = GltfOptions {
        default_light: true,
        // Keep libFuzzer's 2 GiB RSS limit out of reach.
        memory_limit: 256 << 20,
    };
    let _ = load_gltf_slice(data, None, "fuzz.gltf", &opts);
});

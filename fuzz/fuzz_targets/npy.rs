//! `.npy` normal maps (header checked before any allocation).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = photostereo::io::groundtruth::decode_npy(data);
});

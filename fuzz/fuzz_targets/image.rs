//! PNG, TIFF and OpenEXR decoding (the format is sniffed from the first bytes).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = photostereo::io::imageio::decode_image(data);
});

//! Light-direction files (N rows `x y z`, optional count line), then the rank check.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = photostereo::io::limits::text_from_bytes(data) {
        let path = std::path::Path::new("light_directions.txt");
        if let Ok(lights) = photostereo::io::light_files::parse_directions(&text, path) {
            let _ = lights.check_rank();
        }
    }
});

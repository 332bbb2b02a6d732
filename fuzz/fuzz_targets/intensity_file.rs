//! Light-intensity files (N rows `R G B` or one value, optional count line).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = photostereo::io::limits::text_from_bytes(data) {
        let path = std::path::Path::new("light_intensities.txt");
        let _ = photostereo::io::light_files::parse_intensity_rows(&text, path, Some(4));
        let _ = photostereo::io::light_files::parse_intensity_rows(&text, path, None);
    }
});

//! `cargo fuzz run mrclam`: see fuzz/README.md.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    slam_fuzz::Target::Mrclam.run(data);
});

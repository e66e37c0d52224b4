//! `cargo fuzz run mcap`: see fuzz/README.md.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    slam_fuzz::Target::Mcap.run(data);
});

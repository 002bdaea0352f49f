//! The option parser: any name and value given to `Options::set` (as the
//! bindings pass them) is either taken, leaving options that pass
//! `validate()`, or refused with an error that names the option, leaving the
//! options unchanged. It must never panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use pgo::Options;

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    // Lines of `name=value`: each set in turn on the same options.
    let mut options = Options::default();
    for line in text.lines().take(16) {
        let (name, value) = line.split_once('=').unwrap_or((line, ""));
        let before = options.clone();
        match options.set(name, value) {
            Ok(()) => assert!(options.validate().is_ok(), "{name}={value}: {options:?}"),
            Err(e) => {
                assert_eq!(options, before, "{name}={value}: a refusal changed the options");
                assert!(!e.to_string().is_empty());
            }
        }
    }
});

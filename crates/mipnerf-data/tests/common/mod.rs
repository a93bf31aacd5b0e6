//! What the data crate's fuzzing tests share.

use mipnerf_core::test_support::fuzz_cases;
use proptest::prelude::ProptestConfig;

/// The fuzzing proptests' settings: [`fuzz_cases`] cases, no failure files written.
pub fn fuzz_config() -> ProptestConfig {
    ProptestConfig { cases: fuzz_cases(), failure_persistence: None, ..Default::default() }
}

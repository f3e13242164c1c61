//! End-to-end tests: the `handeye` binary against the simulators.

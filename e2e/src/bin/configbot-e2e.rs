//! The `configbot` program, built inside the e2e package for its tests.

fn main() -> std::process::ExitCode {
    configbot::main()
}

//! The `configbot` command: control plane (`serve`), client commands
//! (`apply`, `get`, `describe`, `delete`), offline `validate`, and `demo`.
//! The commands live in the library (`configbot_controller::cli`) so the
//! end-to-end tests build and run exactly this program.

fn main() -> std::process::ExitCode {
    configbot_controller::cli::main()
}

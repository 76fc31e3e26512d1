//! The `configbot` command: control plane (`serve`), client commands
//! (`apply`, `get`, `describe`, `delete`), offline `validate`, and `demo`.

mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}

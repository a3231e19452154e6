//! `deltaloop`: the supervisor CLI.
fn main() -> std::process::ExitCode {
    deltaloop_supervisor::cmd::main()
}

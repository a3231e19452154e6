//! `deltaloop-bridge`: carries one run between two hosts, started by `deltaloop run
//! --controller-remote` (near side) and `deltaloop join` (far side).
fn main() -> std::process::ExitCode {
    deltaloop_bridge::main()
}

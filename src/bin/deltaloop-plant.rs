//! `deltaloop-plant`: the plant process, started by `deltaloop run`; across two hosts over the
//! link's socket its bridge hands on at START, else over iceoryx2.
fn main() -> std::process::ExitCode {
    deltaloop_plant::process::main(deltaloop_link::Handoff::default())
}

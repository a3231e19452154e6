//! The transport's contracts from outside, as a process that uses them sees them: the wire
//! messages' texts, kinds and layouts, the exit codes, and the services' slots and shared-memory
//! check. (Here rather than as unit tests: a unit-test build compiles the crate's iceoryx2
//! services a second time, 20 s of CPU in every clean test build.)

mod exit {
    use deltaloop_transport::exit::*;

    #[test]
    fn each_end_has_its_own_code() {
        assert_eq!(ProcessEnd::Completed.code(), 0);
        assert_eq!(ProcessEnd::Fault("x".into()).code(), EXIT_FAULT);
        assert_eq!(ProcessEnd::Stopped("x".into()).code(), EXIT_STOPPED);
        assert_eq!(ProcessEnd::PeerSilent("x".into()).code(), EXIT_PEER_SILENT);
        let codes = [
            EXIT_USAGE,
            EXIT_SETUP,
            EXIT_FAULT,
            EXIT_STOPPED,
            EXIT_PEER_SILENT,
        ];
        for (i, a) in codes.iter().enumerate() {
            assert!(codes[i + 1..].iter().all(|b| a != b), "{codes:?}");
        }
    }
}

mod ipc {
    use deltaloop_transport::ipc::*;

    /// Regression: a process that took the `state` publisher slot before the plant had the run
    /// blame the plant, without a word about who held the slot.
    #[test]
    fn regression_a_taken_publisher_slot_names_the_process_that_holds_it() {
        let run_id = format!("slot-{:x}", std::process::id());
        let stranger = node("stranger", &run_id).unwrap();
        // The stranger opens the plant's ports, the `state` publisher first (the test's own
        // publisher would compile iceoryx2's port set-up once more into this binary: 28 s of CPU).
        let _held = plant_loop(&stranger, &run_id, LOOP_BUFFER).unwrap();
        let plant = node("plant", &run_id).unwrap();
        let e = plant_loop(&plant, &run_id, LOOP_BUFFER).err().unwrap();
        let line = e.to_string();
        assert!(
            line.contains("publisher on state")
                && line.contains(&format!(
                    "held by another process (pid {}",
                    std::process::id()
                )),
            "{line}"
        );
    }

    #[test]
    fn shm_check_names_free_and_needed_space() {
        let need = shm_needed_bytes();
        // ≈ 19.2 MiB, whatever the run's length: three fit in Docker's 64 MiB, not four.
        assert!((19 << 20..20 << 20).contains(&need), "{need}");
        assert!(check_shm(3 * need, 64 << 20).is_ok());
        assert!(check_shm(4 * need, 64 << 20).is_err());
        let err = check_shm(need, 8 << 20).unwrap_err();
        assert!(
            err.contains("8.0 MiB free") && err.contains("--shm-size"),
            "{err}"
        );
        assert_eq!(err.lines().count(), 1);
    }
}

mod wire {
    use deltaloop_transport::wire::*;

    #[test]
    fn fault_text_round_trips_and_truncates_on_char_boundary() {
        let m = ControlMsg::with_text(ControlKind::Fault, Sender::Plant, 7, "left the workspace");
        assert_eq!(m.text(), "left the workspace");
        assert_eq!(m.tick, 7);
        assert_eq!(
            (m.kind(), m.sender()),
            (Some(ControlKind::Fault), Some(Sender::Plant))
        );
        let long = "é".repeat(200);
        let t = ControlMsg::with_text(ControlKind::Fault, Sender::Plant, 0, &long).text();
        assert!(t.len() <= 160 && t.chars().all(|c| c == 'é'));
    }
    #[test]
    fn control_kinds_and_senders_round_trip_and_unknown_values_are_none() {
        for k in [
            ControlKind::Ready,
            ControlKind::Start,
            ControlKind::Stop,
            ControlKind::Fault,
            ControlKind::Armed,
            ControlKind::Diverged,
            ControlKind::Stopped,
            ControlKind::Overrun,
            ControlKind::PlantError,
            ControlKind::ControllerError,
        ] {
            assert_eq!(ControlKind::from_wire(k as u32), Some(k));
        }
        assert_eq!(ControlKind::from_wire(5), None);
        assert_eq!(Sender::from_wire(3), Some(Sender::Supervisor));
        assert_eq!(Sender::from_wire(0), None);
    }
    /// Regression: a controller's DIVERGED text with escape codes and a newline landed verbatim
    /// in summary.json and report.md (and on the terminal).
    #[test]
    fn regression_peer_text_with_escape_codes_and_newlines_is_escaped() {
        let m = ControlMsg::with_text(
            ControlKind::Diverged,
            Sender::Plant,
            3,
            "bad\x1b[2J\nnext line\u{202e}é\t",
        );
        assert_eq!(m.text(), "bad\\u{1b}[2J\\nnext line\\u{202e}é\\t");
        assert_eq!(m.text().lines().count(), 1);
        let mut raw = ControlMsg::new(ControlKind::Fault, Sender::Plant);
        raw.text[..3].copy_from_slice(&[b'a', 0xff, b'b']);
        assert_eq!(raw.text(), "a\u{fffd}b");
    }
    /// The reference row's layout is part of the wire format (its type name says v2): pin it.
    #[test]
    fn ref_sample_layout_is_fixed() {
        use std::mem::{align_of, offset_of, size_of};
        assert_eq!(size_of::<RefSample>(), 80);
        assert_eq!(align_of::<RefSample>(), 8);
        assert_eq!(
            [
                offset_of!(RefSample, tick),
                offset_of!(RefSample, q),
                offset_of!(RefSample, qd),
                offset_of!(RefSample, qdd)
            ],
            [0, 8, 32, 56]
        );
    }
}

//! The expected memory layout of every type in the contract, in one table: iceoryx2 type name,
//! size, alignment, and each field's offset and size in bytes. `tests/layout.rs` checks the Rust
//! types against it; C, C++ and Python definitions are checked against the same numbers.
//! Fields are listed in memory order and leave no gaps (no implicit padding).

/// One field: name, offset, size.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FieldLayout {
    pub name: &'static str,
    pub offset: usize,
    pub size: usize,
}

/// One type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TypeLayout {
    /// The Rust name.
    pub name: &'static str,
    /// The iceoryx2 type name (what C, C++ and Python must declare).
    pub type_name: &'static str,
    pub size: usize,
    pub align: usize,
    pub fields: &'static [FieldLayout],
}

const fn f(name: &'static str, offset: usize, size: usize) -> FieldLayout {
    FieldLayout { name, offset, size }
}

/// Every type of the contract.
pub const LAYOUTS: &[TypeLayout] = &[
    TypeLayout {
        name: "BlackboardKey",
        type_name: "UssBlackboardKey",
        size: 4,
        align: 4,
        fields: &[f("value", 0, 4)],
    },
    TypeLayout {
        name: "PzdOutput",
        type_name: "UssPzdOutputV1",
        size: 64,
        align: 8,
        fields: &[
            f("version", 0, 4),
            f("controller_pid", 4, 4),
            f("sequence", 8, 8),
            f("timestamp_ns", 16, 8),
            f("stw1", 24, 2),
            f("setpoint", 26, 2),
            f("extra", 28, 28),
            f("word_count", 56, 1),
            f("reserved", 57, 7),
        ],
    },
    TypeLayout {
        name: "PzdInput",
        type_name: "UssPzdInputV1",
        size: 64,
        align: 8,
        fields: &[
            f("version", 0, 4),
            f("online", 4, 1),
            f("watchdog_tripped", 5, 1),
            f("word_count", 6, 1),
            f("reserved", 7, 1),
            f("sequence", 8, 8),
            f("timestamp_ns", 16, 8),
            f("age_ns", 24, 8),
            f("zsw1", 32, 2),
            f("hiw", 34, 2),
            f("extra", 36, 28),
        ],
    },
    TypeLayout {
        name: "DriveDiag",
        type_name: "UssDriveDiagV1",
        size: 200,
        align: 8,
        fields: &[
            f("version", 0, 4),
            f("consecutive_failed_polls", 4, 4),
            f("last_zsw1", 8, 2),
            f("last_hiw", 10, 2),
            f("address", 12, 1),
            f("online", 13, 1),
            f("no_reply", 14, 1),
            f("watchdog_tripped", 15, 1),
            f("last_failure", 16, 1),
            f("reserved", 17, 7),
            f("since_ns", 24, 8),
            f("last_good_ns", 32, 8),
            f("requests", 40, 8),
            f("good", 48, 8),
            f("rejected", 56, 8),
            f("timeouts", 64, 8),
            f("retries", 72, 8),
            f("failed_polls", 80, 8),
            f("missing_stx", 88, 8),
            f("start_pause", 96, 8),
            f("bad_lge", 104, 8),
            f("bcc", 112, 8),
            f("residual", 120, 8),
            f("length", 128, 8),
            f("wrong_address", 136, 8),
            f("parity", 144, 8),
            f("framing", 152, 8),
            f("overrun", 160, 8),
            f("echo", 168, 8),
            f("pkw_busy", 176, 8),
            f("jobs_done", 184, 8),
            f("watchdog_trips", 192, 8),
        ],
    },
    TypeLayout {
        name: "BusStatus",
        type_name: "UssBusStatusV1",
        size: 104,
        align: 8,
        fields: &[
            f("version", 0, 4),
            f("rt_cpu", 4, 4),
            f("rt_mode", 8, 1),
            f("rt_priority", 9, 1),
            f("drive_count", 10, 1),
            f("running", 11, 1),
            f("efficiency_ppm", 12, 4),
            f("exchanges", 16, 8),
            f("good", 24, 8),
            f("cycles", 32, 8),
            f("cycle_overruns", 40, 8),
            f("events_dropped", 48, 8),
            f("results_lost", 56, 8),
            f("jobs_accepted", 64, 8),
            f("jobs_finished", 72, 8),
            f("mean_exchange_ns", 80, 8),
            f("bus_clock_ns", 88, 8),
            f("timestamp_ns", 96, 8),
        ],
    },
    TypeLayout {
        name: "ParamItem",
        type_name: "UssParamItemV1",
        size: 12,
        align: 4,
        fields: &[
            f("task", 0, 1),
            f("storage", 1, 1),
            f("pnu", 2, 2),
            f("index", 4, 2),
            f("reserved", 6, 2),
            f("value", 8, 4),
        ],
    },
    TypeLayout {
        name: "ParamRequest",
        type_name: "UssParamRequestV1",
        size: 476,
        align: 4,
        fields: &[
            f("version", 0, 4),
            f("address", 4, 1),
            f("count", 5, 1),
            f("reserved", 6, 2),
            f("items", 8, 468),
        ],
    },
    TypeLayout {
        name: "ParamResult",
        type_name: "UssParamResultV1",
        size: 24,
        align: 8,
        fields: &[
            f("outcome", 0, 1),
            f("value_is_dword", 1, 1),
            f("drive_error", 2, 2),
            f("value", 4, 4),
            f("telegrams", 8, 4),
            f("refusal", 12, 1),
            f("reserved", 13, 3),
            f("on_wire_ns", 16, 8),
        ],
    },
    TypeLayout {
        name: "ParamResponse",
        type_name: "UssParamResponseV1",
        size: 944,
        align: 8,
        fields: &[
            f("version", 0, 4),
            f("error", 4, 1),
            f("error_item", 5, 1),
            f("address", 6, 1),
            f("count", 7, 1),
            f("results", 8, 936),
        ],
    },
];

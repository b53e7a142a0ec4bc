//! proptest strategies for every message of the protocol (shared by the test files).
#![allow(dead_code)]

use heapless::{String, Vec};
use proptest::prelude::*;
use proptest::strategy::BoxedStrategy;
use protocol::*;

pub fn angle() -> BoxedStrategy<Angle> {
    prop_oneof![
        any::<i32>().prop_map(Angle::from_ticks),
        (0i32..=6800).prop_map(Angle::from_ticks)
    ]
    .boxed()
}

pub fn geometry() -> BoxedStrategy<Geometry> {
    (angle(), angle())
        .prop_map(|(i, r)| Geometry::new(i, r))
        .boxed()
}

pub fn target() -> BoxedStrategy<Target> {
    prop_oneof![Just(Target::Sample), Just(Target::WhiteReference)].boxed()
}

fn finite_f32() -> BoxedStrategy<f32> {
    prop_oneof![
        -1e30f32..1e30f32,
        Just(0.0f32),
        Just(f32::MAX),
        Just(f32::MIN_POSITIVE)
    ]
    .boxed()
}

pub fn error_code() -> BoxedStrategy<ErrorCode> {
    any::<u16>().prop_map(ErrorCode::from).boxed()
}

pub fn command() -> BoxedStrategy<Command> {
    let chunk = (
        any::<u16>(),
        any::<u16>(),
        any::<u16>(),
        proptest::collection::vec(geometry(), 0..=SCHEDULE_CHUNK_LEN),
    )
        .prop_map(|(schedule_id, total_len, offset, gs)| {
            Command::UploadSchedule(ScheduleChunk {
                schedule_id,
                total_len,
                offset,
                geometries: Vec::from_slice(&gs).unwrap(),
            })
        });
    let run = (any::<u16>(), any::<bool>(), any::<u16>(), target()).prop_map(
        |(schedule_id, builtin, integration_ms, target)| {
            Command::RunSchedule(RunSchedule {
                schedule_id,
                source: if builtin {
                    ScheduleSource::Strategy1
                } else {
                    ScheduleSource::Uploaded
                },
                integration_ms,
                target,
            })
        },
    );
    let sweep = (
        any::<u16>(),
        angle(),
        angle(),
        angle(),
        any::<u32>(),
        any::<u16>(),
        proptest::option::of(any::<u8>()),
        any::<bool>(),
    )
        .prop_map(
            |(sweep_id, theta_i, from, to, speed_mdeg_per_s, bin_ticks, range, white)| {
                let target = if white {
                    Target::WhiteReference
                } else {
                    Target::Sample
                };
                Command::Sweep(Sweep {
                    sweep_id,
                    theta_i,
                    from,
                    to,
                    speed_mdeg_per_s,
                    bin_ticks,
                    range,
                    target,
                })
            },
        );
    prop_oneof![
        any::<u16>().prop_map(|protocol_version| Command::Hello { protocol_version }),
        Just(Command::Heartbeat),
        Just(Command::GetStatus),
        Just(Command::Home),
        geometry().prop_map(Command::MoveTo),
        any::<bool>().prop_map(|on| Command::SetLamp { on }),
        any::<u16>().prop_map(|integration_ms| Command::TakeDark { integration_ms }),
        (any::<u16>(), target(), proptest::option::of(any::<u8>())).prop_map(
            |(integration_ms, target, range)| Command::TakeReading {
                integration_ms,
                target,
                range
            }
        ),
        chunk,
        run,
        Just(Command::Abort),
        sweep,
    ]
    .boxed()
}

pub fn request() -> BoxedStrategy<Request> {
    (any::<u32>(), command())
        .prop_map(|(seq, command)| Request { seq, command })
        .boxed()
}

pub fn reading() -> BoxedStrategy<Reading> {
    (
        finite_f32(),
        finite_f32(),
        any::<u32>(),
        any::<u8>(),
        any::<u16>(),
        any::<bool>(),
    )
        .prop_map(
            |(mean_counts, std_counts, samples, range, integration_ms, saturated)| Reading {
                mean_counts,
                std_counts,
                samples,
                range,
                integration_ms,
                saturated,
            },
        )
        .boxed()
}

fn text<const N: usize>() -> impl Strategy<Value = String<N>> {
    proptest::string::string_regex(&format!("[ -~]{{0,{N}}}"))
        .unwrap()
        .prop_map(|s| String::try_from(s.as_str()).unwrap())
}

pub fn device_info() -> BoxedStrategy<DeviceInfo> {
    let ranges = proptest::collection::vec(
        (finite_f32(), any::<u32>(), finite_f32(), any::<u32>()).prop_map(
            |(relative_gain, full_scale_counts, time_constant_us, settle_us)| DetectorRange {
                relative_gain,
                full_scale_counts,
                time_constant_us,
                settle_us,
            },
        ),
        0..=MAX_RANGES,
    );
    (
        (
            any::<u16>(),
            text::<16>(),
            text::<32>(),
            angle(),
            angle(),
            angle(),
            angle(),
        ),
        (
            finite_f32(),
            finite_f32(),
            any::<u16>(),
            ranges,
            finite_f32(),
            any::<u16>(),
            any::<u16>(),
            any::<u16>(),
        ),
        (
            any::<u16>(),
            any::<u32>(),
            any::<u32>(),
            text::<24>(),
            reset_cause(),
            any::<u32>(),
        ),
    )
        .prop_map(
            |(
                (
                    protocol_version,
                    firmware_version,
                    board,
                    arm_min,
                    arm_max,
                    arm_resolution,
                    collision_min_sum,
                ),
                (
                    max_speed,
                    accel,
                    settle_ms,
                    ranges,
                    acceptance_deg,
                    max_schedule_len,
                    default_integration_ms,
                    max_integration_ms,
                ),
                (
                    min_integration_ms,
                    heartbeat_timeout_ms,
                    longest_home_ms,
                    serial_number,
                    reset_cause,
                    detector_block_us,
                ),
            )| DeviceInfo {
                protocol_version,
                firmware_version,
                board,
                arm_min,
                arm_max,
                arm_resolution,
                collision_min_sum,
                max_speed_deg_per_s: max_speed,
                accel_deg_per_s2: accel,
                settle_ms,
                detector_ranges: Vec::from_slice(&ranges).unwrap(),
                acceptance_deg,
                max_schedule_len,
                default_integration_ms,
                max_integration_ms,
                min_integration_ms,
                heartbeat_timeout_ms,
                longest_home_ms,
                serial_number,
                reset_cause,
                detector_block_us,
            },
        )
        .boxed()
}

pub fn reset_cause() -> BoxedStrategy<ResetCause> {
    prop_oneof![
        Just(ResetCause::PowerOn),
        Just(ResetCause::ResetPin),
        Just(ResetCause::Software),
        Just(ResetCause::Watchdog),
        (error_code(), any::<i32>())
            .prop_map(|(code, detail)| ResetCause::Fault(DeviceError::with_detail(code, detail))),
    ]
    .boxed()
}

fn state() -> BoxedStrategy<DeviceState> {
    prop_oneof![
        Just(DeviceState::Idle),
        Just(DeviceState::Homing),
        Just(DeviceState::Moving),
        Just(DeviceState::Measuring),
        Just(DeviceState::RunningSchedule),
        Just(DeviceState::Stopped),
        Just(DeviceState::Sweeping),
    ]
    .boxed()
}

pub fn reply() -> BoxedStrategy<Reply> {
    let status = (
        state(),
        geometry(),
        any::<[bool; 3]>(),
        proptest::option::of(error_code()),
        proptest::option::of(any::<(u16, u16)>()),
        any::<u64>(),
    )
        .prop_map(
            |(state, position, [homed_i, homed_r, lamp_on], fault, schedule, uptime_us)| {
                Reply::Status(Status {
                    state,
                    position,
                    homed_i,
                    homed_r,
                    lamp_on,
                    fault,
                    schedule,
                    uptime_us,
                })
            },
        );
    prop_oneof![
        device_info().prop_map(Reply::Hello),
        Just(Reply::Ack),
        status,
        (
            proptest::option::of(any::<i32>()),
            proptest::option::of(any::<i32>())
        )
            .prop_map(|(step_error_i, step_error_r)| Reply::Homed(HomeReport {
                step_error_i,
                step_error_r
            })),
        reading().prop_map(Reply::Reading),
        proptest::collection::vec(reading(), 0..=MAX_RANGES)
            .prop_map(|rs| Reply::Dark(Vec::from_slice(&rs).unwrap())),
        any::<(u16, u16, u16)>().prop_map(|(schedule_id, received, total_len)| {
            Reply::ScheduleLoaded {
                schedule_id,
                received,
                total_len,
            }
        }),
        any::<(u16, u16)>()
            .prop_map(|(schedule_id, len)| Reply::ScheduleStarted { schedule_id, len }),
        any::<(u16, u32)>()
            .prop_map(|(bins, duration_ms)| Reply::Sweep(SweepPlan { bins, duration_ms })),
    ]
    .boxed()
}

pub fn device_message() -> BoxedStrategy<DeviceMessage> {
    let result = prop_oneof![
        reply().prop_map(Ok),
        (error_code(), any::<i32>()).prop_map(|(code, detail)| Err(DeviceError { code, detail })),
    ];
    let stream = (
        any::<u16>(),
        any::<u16>(),
        geometry(),
        target(),
        reading(),
        any::<u64>(),
    )
        .prop_map(
            |(schedule_id, index, geometry, target, reading, device_time_us)| {
                DeviceMessage::Reading(StreamReading {
                    schedule_id,
                    index,
                    geometry,
                    target,
                    reading,
                    device_time_us,
                })
            },
        );
    prop_oneof![
        (any::<u32>(), result).prop_map(|(seq, result)| DeviceMessage::Reply { seq, result }),
        stream,
        (
            any::<u16>(),
            any::<u16>(),
            any::<u64>(),
            proptest::option::of(error_code())
        )
            .prop_map(|(schedule_id, readings, device_us, error)| {
                DeviceMessage::ScheduleDone(ScheduleDone {
                    schedule_id,
                    readings,
                    device_us,
                    error,
                })
            }),
        error_code().prop_map(|code| DeviceMessage::FrameRejected { code }),
        error_code().prop_map(|reason| DeviceMessage::Stopped { reason }),
        sweep_bin().prop_map(DeviceMessage::SweepBin),
        any::<(u16, u16)>()
            .prop_map(|(sweep_id, bins)| DeviceMessage::SweepDone { sweep_id, bins }),
    ]
    .boxed()
}

pub fn sweep_bin() -> BoxedStrategy<SweepBin> {
    (
        (any::<u16>(), any::<u16>(), angle(), angle()),
        (
            finite_f32(),
            finite_f32(),
            any::<u16>(),
            any::<u8>(),
            any::<u8>(),
            any::<u64>(),
        ),
    )
        .prop_map(
            |(
                (sweep_id, index, start, end),
                (mean_counts, std_counts, blocks, range, flags, device_time_us),
            )| SweepBin {
                sweep_id,
                index,
                start,
                end,
                mean_counts,
                std_counts,
                blocks,
                range,
                flags,
                device_time_us,
            },
        )
        .boxed()
}

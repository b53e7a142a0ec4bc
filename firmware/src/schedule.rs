//! Schedules: the built-in Strategy 1 in its fixed visiting order, and schedules uploaded
//! by the host in chunks (run in the order given: the host plans, the instrument executes).

use protocol::schedules::MAX_SCHEDULE_LEN;
use protocol::{DeviceError, ErrorCode, Geometry, ScheduleChunk};

/// Strategy 1 with M = 12 (the geometries of `protocol::schedules::strategy1(12)`), in the
/// order the device visits them.
///
/// How it was chosen: the time of a move is the fastest trapezoid of the longer of the two
/// arm travels (the arms arrive together, [`crate::motion`]), so the order that minimises
/// the total move time was found by exhaustive dynamic programming over the 2¹² subsets
/// (Held–Karp), starting from where homing leaves both arms (the home switches, 87.5°).
/// The test `strategy1_order_is_optimal` in `tests/it/schedules.rs` re-runs that search with
/// the library's own motion planner. The order sweeps the θr = 70° row from the home side,
/// comes down the specular diagonal, and ends along θr = 0:
/// total move time 6.98 s, against 13.6 s for the paper's order (θi, then θr).
pub const STRATEGY1_ORDER: [Geometry; 12] = [
    Geometry::from_whole_deg(60, 70),
    Geometry::from_whole_deg(60, 60),
    Geometry::from_whole_deg(45, 70),
    Geometry::from_whole_deg(30, 70),
    Geometry::from_whole_deg(20, 70),
    Geometry::from_whole_deg(45, 45),
    Geometry::from_whole_deg(30, 30),
    Geometry::from_whole_deg(20, 20),
    Geometry::from_whole_deg(20, 0),
    Geometry::from_whole_deg(30, 0),
    Geometry::from_whole_deg(45, 0),
    Geometry::from_whole_deg(60, 0),
];

/// A schedule uploaded by the host, possibly still incomplete.
#[derive(Clone, Debug, Default)]
pub struct UploadedSchedule {
    schedule_id: u16,
    total_len: u16,
    geometries: heapless::Vec<Geometry, MAX_SCHEDULE_LEN>,
}

impl UploadedSchedule {
    /// Nothing uploaded.
    pub const fn new() -> UploadedSchedule {
        UploadedSchedule {
            schedule_id: 0,
            total_len: 0,
            geometries: heapless::Vec::new(),
        }
    }

    /// Take one chunk. `max_len` is the device's limit; `check` validates each geometry
    /// (range, collision guard) so that a bad schedule is refused at upload, not mid-run.
    /// Returns the number of geometries received so far.
    pub fn add_chunk(
        &mut self,
        chunk: &ScheduleChunk,
        max_len: u16,
        check: impl Fn(Geometry) -> Result<(), DeviceError>,
    ) -> Result<u16, DeviceError> {
        if usize::from(chunk.total_len) > usize::from(max_len).min(MAX_SCHEDULE_LEN) {
            return Err(DeviceError::with_detail(
                ErrorCode::ScheduleTooLong,
                i32::from(max_len),
            ));
        }
        let continues = chunk.offset != 0;
        let expected = if continues
            && chunk.schedule_id == self.schedule_id
            && chunk.total_len == self.total_len
        {
            self.geometries.len() as u16
        } else {
            0
        };
        let end = usize::from(chunk.offset) + chunk.geometries.len();
        if chunk.total_len == 0 || chunk.offset != expected || end > usize::from(chunk.total_len) {
            return Err(DeviceError::with_detail(
                ErrorCode::BadSchedule,
                i32::from(expected),
            ));
        }
        for &geometry in &chunk.geometries {
            check(geometry)?;
        }
        if !continues {
            self.schedule_id = chunk.schedule_id;
            self.total_len = chunk.total_len;
            self.geometries.clear();
        }
        // Fits: end ≤ total_len ≤ capacity, checked above.
        let _ = self.geometries.extend_from_slice(&chunk.geometries);
        Ok(self.geometries.len() as u16)
    }

    /// The complete schedule with this id, if there is one.
    pub fn complete(&self, schedule_id: u16) -> Option<&[Geometry]> {
        let complete = self.total_len > 0 && self.geometries.len() == usize::from(self.total_len);
        (complete && self.schedule_id == schedule_id).then_some(self.geometries.as_slice())
    }

    /// Geometry `index` (of a complete schedule).
    pub fn get(&self, index: u16) -> Option<Geometry> {
        self.geometries.get(usize::from(index)).copied()
    }
}

//! The firmware's own control-period grid: how many whole periods a `DeviceApp::step` at a
//! given local time has to run, with a bounded catch-up.

/// Tracks the time of the last period a firmware ran.
#[derive(Clone, Copy, Debug, Default)]
pub struct PeriodClock {
    last_time_ns: Option<u64>,
}

impl PeriodClock {
    /// Whole periods of `period_ns` due at `local_time_ns`, at most `max_periods` (beyond it
    /// the firmware "loses" time: a stalled simulator must not spend seconds computing the
    /// past). The first call runs one period; a clock that jumped back by more than a period
    /// (its time was set) re-anchors and runs one.
    pub fn due(&mut self, local_time_ns: u64, period_ns: u64, max_periods: u64) -> u64 {
        let periods = match self.last_time_ns {
            None => 1,
            Some(last) if local_time_ns >= last => {
                (local_time_ns - last + period_ns / 2) / period_ns
            }
            Some(last) if last - local_time_ns > period_ns => 1,
            Some(_) => 0,
        };
        if periods == 0 {
            return 0;
        }
        let run = periods.min(max_periods);
        self.last_time_ns = Some(match self.last_time_ns {
            // Advance by whole periods so the firmware keeps its own grid.
            Some(last) if periods == run && local_time_ns >= last => last + run * period_ns,
            // First call, a clock jump, or a capped catch-up: anchor on the present.
            _ => local_time_ns,
        });
        run
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn whole_periods_on_the_firmware_grid() {
        let mut c = PeriodClock::default();
        assert_eq!(c.due(1_000, 100, 10), 1, "first call");
        assert_eq!(c.due(1_040, 100, 10), 0, "less than half a period");
        assert_eq!(c.due(1_260, 100, 10), 3, "rounded to whole periods");
        assert_eq!(c.due(1_300, 100, 10), 0, "the grid stayed at 1_300");
        assert_eq!(c.due(100_000, 100, 10), 10, "catch-up capped");
        assert_eq!(c.due(100_100, 100, 10), 1, "re-anchored on the present");
        assert_eq!(c.due(50_000, 100, 10), 1, "clock set back");
    }
}

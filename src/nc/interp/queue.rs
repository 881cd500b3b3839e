//! The records a line has produced and not yet handed out, in slots that are reused:
//! a record read is not dropped but overwritten field by field by a later one, so the
//! common straight move is written once, in place, instead of being built and then moved
//! (twice) into a queue — a record is some 230 bytes, and those copies of freshly written
//! memory were a fifth of the interpretation.

use crate::nc::output::{Event, Motion, Record, RecordBody};

/// Records `recs[head..live]` wait to be handed out; `recs[live..]` are spare slots.
#[derive(Default)]
pub(super) struct Queue {
    recs: Vec<Record>,
    head: usize,
    live: usize,
}

/// Where a record comes from.
#[derive(Clone, Copy)]
pub(super) struct Origin {
    pub file: usize,
    pub line: usize,
    pub n: Option<crate::math::Real>,
}

impl Queue {
    pub fn is_empty(&self) -> bool {
        self.head == self.live
    }

    /// The first waiting record.
    pub fn front(&self) -> Option<&Record> {
        self.recs[self.head..self.live].first()
    }

    /// Hands the first waiting record out of the queue (its slot keeps a placeholder).
    pub fn take_front(&mut self) -> Option<Record> {
        if self.is_empty() {
            return None;
        }
        let placeholder = Record {
            body: RecordBody::Event(Event {
                call: "",
                args: Vec::new(),
            }),
            file: 0,
            line: 0,
            n: None,
        };
        let r = std::mem::replace(&mut self.recs[self.head], placeholder);
        self.drop_front();
        Some(r)
    }

    /// Forgets the first waiting record (its slot is reused).
    pub fn drop_front(&mut self) {
        if self.head < self.live {
            self.head += 1;
            if self.head == self.live {
                self.head = 0;
                self.live = 0;
            }
        }
    }

    /// Appends a record.
    pub fn push(&mut self, rec: Record) {
        if self.live < self.recs.len() {
            self.recs[self.live] = rec;
        } else {
            self.recs.push(rec);
        }
        self.live += 1;
    }

    /// Appends a move, written into a spare slot field by field when it holds a move.
    pub fn push_motion(&mut self, at: Origin, m: Motion) {
        if let Some(Record {
            body: RecordBody::Motion(slot),
            file,
            line,
            n,
        }) = self.recs.get_mut(self.live)
        {
            slot.kind = m.kind;
            slot.start = m.start;
            slot.end = m.end;
            slot.feed = m.feed;
            slot.feed_per_rev = m.feed_per_rev;
            slot.arc = m.arc;
            (*file, *line, *n) = (at.file, at.line, at.n);
            self.live += 1;
            return;
        }
        self.push(Record {
            body: RecordBody::Motion(m),
            file: at.file,
            line: at.line,
            n: at.n,
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nc::AxisValues;
    use crate::nc::output::{ArcGeom, MotionKind};

    fn parts(x: f64, arc: bool) -> Motion {
        Motion {
            kind: if arc {
                MotionKind::Arc
            } else {
                MotionKind::Linear
            },
            start: AxisValues::from_array([x - 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
            end: AxisValues::from_array([x, 0.0, 0.0, 0.0, 0.0, 0.0]),
            feed: Some(x),
            feed_per_rev: false,
            arc: arc.then_some(ArcGeom {
                center: crate::math::Point3::new(x, 1.0, 0.0),
                normal: crate::math::Vector3::z(),
                plane: crate::nc::Plane::Xy,
                rotation: 1,
                radius: 1.0,
                radius_end: 1.0,
                sweep_deg: 90.0,
            }),
        }
    }

    fn event(call: &'static str) -> Record {
        Record {
            body: RecordBody::Event(Event {
                call,
                args: Vec::new(),
            }),
            file: 1,
            line: 7,
            n: None,
        }
    }

    fn at(line: usize) -> Origin {
        Origin {
            file: 0,
            line,
            n: Some(line as f64),
        }
    }

    /// A slot that held a move, an arc or an event, reused for another kind, reads exactly
    /// as a freshly built record: nothing of the earlier record is left over.
    #[test]
    fn reused_slots_hold_exactly_the_new_record() {
        let mut q = Queue::default();
        q.push_motion(at(1), parts(1.0, true));
        q.push(event("A"));
        q.push_motion(at(3), parts(3.0, false));
        let expect = |m: Motion, line: usize| Record {
            body: RecordBody::Motion(m),
            file: 0,
            line,
            n: Some(line as f64),
        };
        assert_eq!(q.front(), Some(&expect(parts(1.0, true), 1)));
        q.drop_front();
        assert_eq!(q.take_front(), Some(event("A")));
        assert_eq!(q.front(), Some(&expect(parts(3.0, false), 3)));
        q.drop_front();
        assert!(q.is_empty() && q.front().is_none() && q.take_front().is_none());
        // the arc's slot now takes a straight move, the event's slot a move, the move's an
        // event
        q.push_motion(at(4), parts(4.0, false));
        q.push_motion(at(5), parts(5.0, true));
        q.push(event("B"));
        q.push(event("C"));
        assert_eq!(q.take_front(), Some(expect(parts(4.0, false), 4)));
        assert_eq!(q.take_front(), Some(expect(parts(5.0, true), 5)));
        assert_eq!(q.take_front(), Some(event("B")));
        assert_eq!(q.take_front(), Some(event("C")));
        assert!(q.is_empty());
    }
}

//! Every embedded world by id: the 300 static BARN worlds (0..299) followed by the 60 DynaBARN
//! worlds (300..359), so that an id means one world everywhere (selections, training
//! assignments, results).

use std::sync::OnceLock;

use crate::world::World;

/// Number of embedded worlds: BARN then DynaBARN.
pub const NUM_WORLDS: usize = crate::barn::NUM_WORLDS + crate::dynabarn::NUM_WORLDS;

/// A world id that no embedded world has.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error(
    "world {0} does not exist (BARN has worlds 0..{barn}, DynaBARN {first}..{last})",
    barn = crate::barn::NUM_WORLDS - 1,
    first = crate::dynabarn::FIRST_ID,
    last = NUM_WORLDS - 1
)]
pub struct UnknownWorld(pub usize);

/// All embedded worlds, world `id` at index `id` (parsed once, on first use; the BARN and
/// DynaBARN modules hand out slices of this one list).
pub fn worlds() -> &'static [World] {
    static WORLDS: OnceLock<Vec<World>> = OnceLock::new();
    WORLDS.get_or_init(|| {
        let barn = crate::barn::parse(
            "obstacles.jsonl",
            crate::barn::OBSTACLES_JSONL,
            "paths.jsonl",
            crate::barn::PATHS_JSONL,
        )
        .expect("the embedded BARN data is checked by the test suite");
        let dynabarn = crate::dynabarn::parse("dynabarn/obstacles.jsonl", crate::dynabarn::OBSTACLES_JSONL)
            .expect("the embedded DynaBARN data is checked by the test suite");
        barn.into_iter().chain(dynabarn).collect()
    })
}

/// The embedded BARN worlds (ids 0..299, the first part of [`worlds`]).
pub fn barn_worlds() -> &'static [World] {
    &worlds()[..crate::barn::NUM_WORLDS]
}

/// The embedded DynaBARN worlds, world `FIRST_ID + j` at index j (the last part of
/// [`worlds`]).
pub fn dynabarn_worlds() -> &'static [World] {
    &worlds()[crate::dynabarn::FIRST_ID..]
}

/// One embedded world by id.
pub fn world(id: usize) -> Result<&'static World, UnknownWorld> {
    worlds().get(id).ok_or(UnknownWorld(id))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_are_positions() {
        assert_eq!(worlds().len(), 360);
        assert!(worlds().iter().enumerate().all(|(i, w)| w.id == i));
        assert!(world(299).unwrap().moving.is_empty());
        assert!(!world(300).unwrap().moving.is_empty());
        assert_eq!(barn_worlds().len(), 300);
        assert_eq!(dynabarn_worlds()[0].id, 300);
        assert_eq!(
            world(360).unwrap_err().to_string(),
            "world 360 does not exist (BARN has worlds 0..299, DynaBARN 300..359)"
        );
    }
}

//! Every world by id: the 300 static BARN worlds (0..299) followed by the 60 DynaBARN worlds
//! (300..359), both embedded, and the procedural worlds from [`GENERATED_FIRST`] on, made on
//! demand; so an id means one world everywhere (selections, training assignments, results).

use std::borrow::Cow;
use std::sync::OnceLock;

use crate::generate::{GenerateError, GeneratorConfig};
use crate::grid::{Cell, Grid, ROBOT_RADIUS_CELLS};
use crate::metrics::Metrics;
use crate::world::World;

/// Number of embedded worlds: BARN then DynaBARN.
pub const NUM_WORLDS: usize = crate::barn::NUM_WORLDS + crate::dynabarn::NUM_WORLDS;

/// First id of the generated worlds: id `GENERATED_FIRST + k` is world k of the procedural
/// generator ([`crate::generate`]) under [`GENERATED_SEED`] with its default (BARN) settings,
/// the world `adp worlds generate --seed 1` writes as world k.
pub const GENERATED_FIRST: usize = 1_000_000;
/// How many generated ids there are (`GENERATED_FIRST..GENERATED_FIRST + GENERATED_COUNT`;
/// the ids fit the wire's 32-bit world field).
pub const GENERATED_COUNT: usize = 1_000_000_000;
/// The generator seed of the generated ids.
pub const GENERATED_SEED: u64 = 1;

/// Whether `id` names a generated world.
pub fn is_generated(id: usize) -> bool {
    (GENERATED_FIRST..GENERATED_FIRST + GENERATED_COUNT).contains(&id)
}

/// A world id that no world has.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error(
    "world {0} does not exist (BARN has worlds 0..{barn}, DynaBARN {first}..{last}, generated \
     {gen_first}..{gen_last})",
    barn = crate::barn::NUM_WORLDS - 1,
    first = crate::dynabarn::FIRST_ID,
    last = NUM_WORLDS - 1,
    gen_first = GENERATED_FIRST,
    gen_last = GENERATED_FIRST + GENERATED_COUNT - 1
)]
pub struct UnknownWorld(pub usize);

/// Why [`load`] has no world for an id.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum LoadError {
    /// No world has the id.
    #[error(transparent)]
    Unknown(#[from] UnknownWorld),
    /// The generator could not make the generated world.
    #[error("generated world {id}: {source}")]
    Generate {
        /// The world id.
        id: usize,
        /// What the generator said.
        source: GenerateError,
    },
}

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

/// The metrics of the 300 embedded BARN worlds, by world id, computed here: on the C-space of
/// each world's grid as rebuilt from its cylinders ([`Grid::from_barn_cylinders`])
/// along its shipped path. (They equal the dataset's published values; `sim/tests/barn_metrics.rs`
/// checks that when the dataset is at hand.)
pub fn barn_metrics() -> &'static [Metrics] {
    static METRICS: OnceLock<Vec<Metrics>> = OnceLock::new();
    METRICS.get_or_init(|| {
        barn_worlds()
            .iter()
            .map(|w| {
                let cspace = Grid::from_barn_cylinders(&w.cylinders).cspace(ROBOT_RADIUS_CELLS);
                let path: Vec<Cell> = w
                    .reference_path
                    .iter()
                    .map(|&p| Cell::from_centre(p).expect("BARN paths run through cell centres"))
                    .collect();
                Metrics::compute(&cspace, &path).expect("BARN paths are free in their C-space")
            })
            .collect()
    })
}

/// One embedded world by id.
pub fn world(id: usize) -> Result<&'static World, UnknownWorld> {
    worlds().get(id).ok_or(UnknownWorld(id))
}

/// One world by id, embedded (borrowed) or generated (made by this call: the generator's
/// automaton, C-space and A*, about 10 ms of CPU for the default settings).
pub fn load(id: usize) -> Result<Cow<'static, World>, LoadError> {
    if is_generated(id) {
        let made = GeneratorConfig::new(GENERATED_SEED)
            .world(id - GENERATED_FIRST)
            .map_err(|source| LoadError::Generate { id, source })?;
        return Ok(Cow::Owned(made.to_world(id)));
    }
    Ok(Cow::Borrowed(world(id)?))
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
            "world 360 does not exist (BARN has worlds 0..299, DynaBARN 300..359, generated \
             1000000..1000999999)"
        );
        assert!(matches!(load(120).unwrap(), Cow::Borrowed(w) if w.id == 120));
        assert_eq!(load(360).unwrap_err(), LoadError::Unknown(UnknownWorld(360)));
        assert_eq!(
            load(GENERATED_FIRST + GENERATED_COUNT).unwrap_err(),
            LoadError::Unknown(UnknownWorld(GENERATED_FIRST + GENERATED_COUNT))
        );
    }

    /// A generated id is the world `adp worlds generate --seed 1` writes at that index, read
    /// back through the BARN file parser as `adp eval --obstacles --paths` reads it.
    #[test]
    fn generated_ids_are_the_generator_files_worlds() {
        let config = GeneratorConfig::new(GENERATED_SEED);
        let (mut obstacles, mut paths) = (String::new(), String::new());
        for k in 0..3 {
            let made = config.world(k).unwrap();
            obstacles += &(made.obstacles_line() + "\n");
            paths += &(made.paths_line(GENERATED_SEED) + "\n");
        }
        let files = crate::barn::parse("obstacles.jsonl", &obstacles, "paths.jsonl", &paths).unwrap();
        for (k, from_file) in files.iter().enumerate() {
            let loaded = load(GENERATED_FIRST + k).unwrap();
            assert_eq!(loaded.id, GENERATED_FIRST + k);
            assert_eq!(loaded.cylinders, from_file.cylinders, "world {k}");
            assert_eq!(loaded.start, from_file.start);
            assert_eq!(loaded.goal, from_file.goal);
            assert_eq!(loaded.path_length_m, from_file.path_length_m);
            assert_eq!(loaded.optimal_time_s, from_file.optimal_time_s);
            assert_eq!(loaded.reference_path, from_file.reference_path);
            assert!(!loaded
                .at(0.0)
                .collides(&crate::geometry::Footprint::JACKAL, &loaded.start));
        }
        assert_ne!(files[0].cylinders, files[1].cylinders);
    }
}

//! Scenes shared by the planner's integration tests.

use sim::{Circle, Vec2, World};

/// A corridor 1.2 m wide along +y with two posts of radius 0.15 m to weave around (at
/// (0.25, 3) and (-0.3, 6)): free stretches, close passes and, for some planners, recovery
/// manoeuvres.
pub fn weaving_corridor() -> World {
    let posts = [
        Circle {
            c: Vec2::new(0.25, 3.0),
            r: 0.15,
        },
        Circle {
            c: Vec2::new(-0.3, 6.0),
            r: 0.15,
        },
    ];
    World::corridor(1.2, &posts)
}

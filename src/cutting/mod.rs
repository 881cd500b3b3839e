//! **Cutting**: the tool swept through the deviated machine carves the stock. Tools as
//! solids of revolution ([`tool`]), the solids a stock or fixture is made of ([`shape`]),
//! the tri-dexel stock with exact surface crossings ([`stock`]), the exact interval of a ray
//! inside a tool swept along a segment ([`cutter`]) or turning with a rotary axis
//! ([`envelope`]), the program driver ([`sweep`]), collision checks riding on it
//! ([`collide`]), the cut part's surface mesh ([`mesh`]), the 3-axis height-field fast
//! path ([`zmap`]) and the part the nominal machine cuts, read near a cut part's surface
//! ([`nominal`]).
//!
//! May use [`crate::math`], [`crate::progress`], [`crate::nc`] (moves) and
//! [`crate::machine`] (tool poses). Knows nothing of scanners, fits, identification or
//! files: meshes and solids are read from text or bytes the caller gives.

pub mod tool;
pub mod shape;
pub mod stock;
pub mod cutter;
pub mod envelope;
pub mod sweep;
pub mod collide;
pub mod mesh;
pub mod adaptive;
pub mod zmap;
pub mod nominal;

//! Baxter & Lin's brush (paper 004, "A Versatile Interactive 3D Brush Model"): spines that
//! find their shape by minimising energy, skinned by the surface the rest of Maobi draws.
//!
//! * [`head`]: brush heads (round, flat, filbert, fan) as sets of spines.
//! * [`skin`]: the surface over the spines as layer rings, and the hair strips between them.

pub mod head;
pub mod skin;

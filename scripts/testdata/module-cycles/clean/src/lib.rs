//! Links are not dependencies: [`crate::p::Q`], [`p::helper`].
pub mod a;
pub mod p;
pub use a::Ay;
pub use p::Q;

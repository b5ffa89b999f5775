mod a;
mod b;
pub mod p;
mod z;
pub use b::Thing;

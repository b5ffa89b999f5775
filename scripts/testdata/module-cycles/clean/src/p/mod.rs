//! A facade: re-exports its child, whose code uses the facade's own item. It also uses `a`,
//! so anything in `a` that counted as a use of `p` would close a circle.
mod q;
pub use self::q::*;
pub use q::Q;
pub fn helper() {
    let _ = crate::Ay;
}

pub struct Ay;
pub fn f() {
    use crate::Thing;
    let _ = Thing;
}

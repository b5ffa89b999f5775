use crate::a::*;
pub fn fc() {
    let _ = Ay;
}

pub fn l() {
    crate::m::top();
}
